"""k-means (Lloyd's algorithm) for an ensemble of seeds, batched like the SOM.

The E members run together: every iteration is one BMU search over all members
(:func:`somtorch.core.distance.bmu_search`, the same search the batch SOM uses) followed by one
accumulation of per-cluster sums in float64 and a division. k-means is the batch SOM with a
neighbourhood of radius 0, so it is the natural baseline for the SOM segmentation.

Member e is seeded with ``seed + e`` through its own :class:`torch.Generator` and evolves exactly
as ``kmeans(x, k, ensemble=1, seed=seed + e)`` would (bitwise on the CPU):

* the initial centres come from :func:`kmeans_init` with that member's generator;
* the BMU of a sample depends only on that member's centres;
* sums and the inertia are added in sample order (``index_add_``), whatever the ensemble size or
  ``chunk_size``;
* a member that has converged is frozen while the others go on.

Empty clusters keep their previous centre. A member stops when an assignment step changes no
label (that step is not counted as an iteration) or when its largest centre shift is ``<= tol``
(that iteration is counted).

Example:
    >>> g = torch.Generator().manual_seed(0)
    >>> x = torch.cat([torch.randn(50, 2, generator=g) * 0.1 + c for c in (0.0, 3.0)])
    >>> res = kmeans(x, 2, ensemble=3, seed=0)
    >>> res.centers.shape, res.inertia.dtype
    (torch.Size([3, 2, 2]), torch.float64)
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass

import torch

from ..core.distance import bmu_search
from ..validation import check_choice, check_positive, check_positive_int, check_tensor

__all__ = ["KMEANS_INITS", "KMeansResult", "kmeans", "kmeans_init"]

KMEANS_INITS = ("kmeans++", "sample")
"""Names accepted by ``init`` (besides a tensor of initial centres)."""

CHUNK_ELEMENTS = 1 << 21  # E · chunk_size bound of the default chunk (≈ 80 MB of temporaries for D = 3)
INIT_ELEMENTS = 1 << 23  # G · N bound of the members seeded together by k-means++ (2 float64 buffers)


@dataclass
class KMeansResult:
    """What :func:`kmeans` returns.

    Attributes:
        centers: cluster centres ``(E, K, D)``, dtype and device of ``x``.
        inertia: per member, the sum over samples of the squared distance to the nearest final
            centre ``(E,)``, float64 (computed in float64, summed in sample order).
        iterations: Lloyd iterations (assignment + update) actually run, the maximum over members.
    """

    centers: torch.Tensor
    inertia: torch.Tensor
    iterations: int


# ----------------------------------------------------------------------------- initialisation
def _init_kmeanspp(x: torch.Tensor, k: int, generators: list[torch.Generator]) -> torch.Tensor:
    """Standard k-means++ seeding (Arthur & Vassilvitskii 2007, one candidate per centre) for G
    members at once, member g drawing only from ``generators[g]``.

    The first centre is a uniformly drawn sample; each further centre is drawn with probability
    proportional to the squared distance to the nearest centre chosen so far (float64; drawn by
    inverting the cumulative sum, so N is not limited as in ``torch.multinomial``). When every
    sample already coincides with a centre (fewer than k distinct samples) the draw is uniform.
    Every operation is elementwise or row-wise, so a member's centres do not depend on G.

    Shape:
        ``x`` ``(N, D)`` → ``(G, K, D)``.
    """
    n = x.shape[0]
    g = len(generators)
    xt = x.double().T.contiguous()  # (D, N): one contiguous row per feature

    def sqdist_to(idx: torch.Tensor) -> torch.Tensor:  # (G,) sample indices → (G, N)
        c = xt[:, idx]  # (D, G)
        out = (xt[0] - c[0, :, None]).square_()
        for dim in range(1, xt.shape[0]):
            out += (xt[dim] - c[dim, :, None]).square_()
        return out

    first = [int(torch.randint(n, (1,), generator=gen)) for gen in generators]
    picks = [torch.tensor(first, device=x.device)]  # K × (G,)
    d2 = sqdist_to(picks[0])  # (G, N) squared distance to the nearest chosen centre
    for _ in range(1, k):
        cum = torch.cumsum(d2, 1)  # (G, N)
        totals = cum[:, -1].tolist()
        u = torch.zeros(g, 1, dtype=torch.float64)
        uniform = {}
        for m, (gen, total) in enumerate(zip(generators, totals)):
            if total > 0.0:
                u[m, 0] = float(torch.rand(1, generator=gen, dtype=torch.float64)) * total
            else:
                uniform[m] = int(torch.randint(n, (1,), generator=gen))
        # first i with cum[i] > u: samples at distance 0 are never drawn
        pick = torch.searchsorted(cum, u.to(x.device), right=True).clamp_max_(n - 1)[:, 0]  # (G,)
        for m, i in uniform.items():
            pick[m] = i
        picks.append(pick)
        torch.minimum(d2, sqdist_to(pick), out=d2)
    return x[torch.stack(picks, 1)].clone()  # (G, K, D)


def _init_sample(x: torch.Tensor, k: int, generators: list[torch.Generator]) -> torch.Tensor:
    """k distinct samples drawn uniformly (a random permutation's first k) per member ``(G, K, D)``."""
    idx = torch.stack([torch.randperm(x.shape[0], generator=gen)[:k] for gen in generators])  # (G, K)
    return x[idx.to(x.device)].clone()


_INITS = {"kmeans++": _init_kmeanspp, "sample": _init_sample}


def _check_generator(generator: torch.Generator) -> None:
    if not isinstance(generator, torch.Generator):
        raise TypeError(f"generator must be a torch.Generator; got {type(generator).__name__} "
                        "(e.g. torch.Generator().manual_seed(0))")
    if generator.device.type != "cpu":
        raise ValueError(f"generator must be a CPU generator; got one on {generator.device}")


def kmeans_init(x: torch.Tensor, k: int, generator: torch.Generator, init: str = "kmeans++") -> torch.Tensor:
    """Initial centres of one k-means run, exactly as :func:`kmeans` draws them for one member.

    ``kmeans(x, k, seed=s)`` starts from ``kmeans_init(x, k, torch.Generator().manual_seed(s), init)``
    (member e of an ensemble from the generator seeded ``seed + e``); pass the result back through
    ``kmeans(..., init=centers)`` or to another implementation to start it from the same point.

    Args:
        x: samples ``(N, D)``, floating point, finite.
        k: number of centres, ``1 <= k <= N``.
        generator: a CPU :class:`torch.Generator`; the only source of randomness (advanced in place).
        init: ``"kmeans++"`` (k-means++ seeding) or ``"sample"`` (k distinct random samples).

    Shape:
        returns ``(K, D)`` in the dtype and on the device of ``x``.

    >>> x = torch.arange(10.0).reshape(5, 2)
    >>> kmeans_init(x, 2, torch.Generator().manual_seed(0), "sample").shape
    torch.Size([2, 2])
    """
    x = _check_x(x)
    k = _check_k(k, x.shape[0])
    _check_generator(generator)
    check_choice("init", init, _INITS)
    return _INITS[init](x, k, [generator])[0]


# ----------------------------------------------------------------------------- Lloyd iterations
def _assign(x: torch.Tensor, centers: torch.Tensor, chunk: int) -> torch.Tensor:
    """Nearest centre of every sample for every member ``(E, N)`` int32 (chunked BMU search)."""
    n = x.shape[0]
    out = torch.empty(centers.shape[0], n, dtype=torch.int32, device=x.device)
    for s in range(0, n, chunk):
        out[:, s:s + chunk] = bmu_search(x[s:s + chunk], centers)  # (E, n)
    return out


def _cluster_sums(x: torch.Tensor, labels: torch.Tensor, k: int,
                  chunk: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-cluster sums (float64, added in sample order) and counts of the samples each centre wins.

    Shape:
        ``x`` ``(N, D)``, ``labels`` ``(E, N)`` → sums ``(E, K, D)`` float64, counts ``(E, K)`` long.
    """
    e, n = labels.shape
    d = x.shape[1]
    sums = torch.zeros(e * k, d, dtype=torch.float64, device=x.device)
    counts = torch.zeros(e * k, dtype=torch.long, device=x.device)
    offs = (torch.arange(e, device=x.device) * k)[:, None]  # (E, 1)
    for s in range(0, n, chunk):
        flat = (labels[:, s:s + chunk].long() + offs).reshape(-1)  # (E*n,), member-major, sample order
        xs = x[s:s + chunk].double()  # (n, D)
        sums.index_add_(0, flat, xs.expand(e, -1, -1).reshape(-1, d))
        counts += torch.bincount(flat, minlength=e * k)
    return sums.view(e, k, d), counts.view(e, k)


def _inertia(x: torch.Tensor, centers: torch.Tensor, labels: torch.Tensor, chunk: int) -> torch.Tensor:
    """Σ_n ‖x_n − c_label(n)‖² per member, float64, summed in sample order ``(E,)``."""
    e, n = labels.shape
    acc = torch.zeros(e, dtype=torch.float64, device=x.device)
    cd = centers.double()
    for s in range(0, n, chunk):
        lab = labels[:, s:s + chunk].long()  # (E, n)
        near = torch.gather(cd, 1, lab[..., None].expand(-1, -1, cd.shape[-1]))  # (E, n, D)
        d2 = (x[s:s + chunk].double() - near).square_().sum(-1)  # (E, n)
        member = torch.arange(e, device=x.device).repeat_interleave(d2.shape[1])  # (E*n,)
        acc.index_add_(0, member, d2.reshape(-1))  # sequential: independent of E and chunking
    return acc


# ----------------------------------------------------------------------------- validation
def _check_x(x: torch.Tensor) -> torch.Tensor:
    check_tensor("x", x, ndim=2, floating=True, finite=True)
    if x.dtype not in (torch.float32, torch.float64):
        raise TypeError(f"x must be float32 or float64; got {x.dtype} (convert with x.float())")
    if x.shape[1] == 0:
        raise ValueError(f"x has no features (shape {tuple(x.shape)}); at least one column is needed")
    return x


def _check_k(k: int, n: int) -> int:
    k = check_positive_int("k", k)
    if n < k:
        raise ValueError(f"k={k} clusters need at least k samples, but x has N={n} rows; "
                         "lower k or pass more data")
    return k


def _check_seed(seed: int) -> int:
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral):
        raise TypeError(f"seed must be an int; got {type(seed).__name__} {seed!r}")
    if seed < 0:
        raise ValueError(f"seed must be >= 0 (member e uses seed + e); got {seed}")
    return int(seed)


def _initial_centers(x: torch.Tensor, k: int, ensemble: int, seed: int,
                     init: str | torch.Tensor) -> torch.Tensor:
    """Initial centres ``(E, K, D)``: drawn per member, or the given tensor checked and copied."""
    if isinstance(init, torch.Tensor):
        check_tensor("init", init, ndim=(2, 3), finite=True)
        want = (k, x.shape[1])
        if init.shape[-2:] != want or (init.ndim == 3 and init.shape[0] != ensemble):
            raise ValueError(f"init as a tensor must have shape {want} or {(ensemble, *want)} "
                             f"(k, D) / (ensemble, k, D); got {tuple(init.shape)}")
        if init.dtype != x.dtype or init.device != x.device:
            raise TypeError(f"init must have the dtype and device of x ({x.dtype}, {x.device}); got "
                            f"{init.dtype}, {init.device} (convert with init.to(x))")
        c = init if init.ndim == 3 else init.expand(ensemble, -1, -1)
        return c.detach().clone().contiguous()
    check_choice("init", init, _INITS)
    generators = [torch.Generator().manual_seed(seed + e) for e in range(ensemble)]
    group = max(1, INIT_ELEMENTS // x.shape[0])  # members seeded together (the result is the same)
    return torch.cat([_INITS[init](x, k, generators[i:i + group]) for i in range(0, ensemble, group)])


# ----------------------------------------------------------------------------- public entry point
@torch.no_grad()
def kmeans(x: torch.Tensor, k: int, *, ensemble: int = 1, seed: int = 0, iterations: int = 20,
           init: str | torch.Tensor = "kmeans++", tol: float = 0.0,
           chunk_size: int | None = None) -> KMeansResult:
    """Lloyd's k-means on ``x`` for ``ensemble`` seeds at once.

    Args:
        x: samples ``(N, D)``, float32 or float64, finite; e.g. scaled ``(y, x, d)`` pixel features.
        k: number of clusters, ``1 <= k <= N``.
        ensemble: number of members E; member e uses seed ``seed + e``.
        seed: base seed (``>= 0``).
        iterations: maximum number of Lloyd iterations per member (``>= 1``).
        init: ``"kmeans++"`` (k-means++ seeding with the member's generator), ``"sample"`` (k distinct
            random samples), or a tensor of initial centres ``(K, D)`` (shared) or ``(E, K, D)`` with
            the dtype and device of ``x`` (see :func:`kmeans_init` to draw them yourself).
        tol: a member stops once its largest centre shift (Euclidean, in the units of ``x``) is
            ``<= tol``; with the default 0 it stops when an assignment step changes no label.
        chunk_size: samples per chunk for the assignment, the sums and the inertia (bounds the
            ``E · chunk_size · D`` float64 temporaries); default ``max(1024, 2**21 // E)``. It does
            not change the result (tested bitwise).

    Returns:
        :class:`KMeansResult` with ``centers`` ``(E, K, D)``, ``inertia`` ``(E,)`` float64 and
        ``iterations`` (the maximum over members).

    Raises:
        TypeError: ``x`` not a floating tensor, or a non-integer ``k``/``ensemble``/``iterations``/
            ``seed``/``chunk_size``.
        ValueError: wrong shape, NaN/inf in ``x``, ``N < k``, values below 1, negative ``tol``,
            unknown ``init`` name — all before any work.

    Shape:
        - x: ``(N, D)``
        - centers: ``(E, K, D)``; inertia: ``(E,)``
    """
    x = _check_x(x)
    k = _check_k(k, x.shape[0])
    ensemble = check_positive_int("ensemble", ensemble)
    seed = _check_seed(seed)
    iterations = check_positive_int("iterations", iterations)
    check_positive("tol", tol, allow_zero=True)
    if chunk_size is None:
        chunk = max(1024, CHUNK_ELEMENTS // ensemble)
    else:
        chunk = check_positive_int("chunk_size", chunk_size)
    if not isinstance(init, torch.Tensor):
        check_choice("init", init, _INITS)

    x = x.detach().contiguous()
    centers = _initial_centers(x, k, ensemble, seed, init)  # (E, K, D)
    active = torch.ones(ensemble, dtype=torch.bool, device=x.device)  # members still iterating
    done = torch.zeros(ensemble, dtype=torch.long, device=x.device)  # iterations run per member
    prev: torch.Tensor | None = None  # the labels the current centres were computed from
    labels = prev
    for _ in range(iterations):
        labels = _assign(x, centers, chunk)  # (E, N)
        if prev is not None:
            active &= (labels != prev).any(1)  # an unchanged assignment would not move the centres
            if not bool(active.any()):
                break
        sums, counts = _cluster_sums(x, labels, k, chunk)  # (E, K, D) float64, (E, K)
        old = centers.double()
        new = torch.where((counts > 0).unsqueeze(-1), sums / counts.clamp_min(1).unsqueeze(-1), old)
        shift = (new - old).square().sum(-1).sqrt().amax(-1)  # (E,) largest centre move
        centers = torch.where(active[:, None, None], new.to(x.dtype), centers)  # converged: frozen
        done += active.long()
        active &= shift > tol
        prev = labels
        if not bool(active.any()):
            break
    if labels is prev:  # the last step moved the centres: assign once more for the inertia
        labels = _assign(x, centers, chunk)
    inertia = _inertia(x, centers, labels, chunk)
    return KMeansResult(centers=centers, inertia=inertia, iterations=int(done.max()))
