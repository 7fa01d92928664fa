"""The ``SOM`` module: an ensemble of E self-organising maps that train together.

>>> import torch
>>> from somtorch import SOM
>>> x = torch.rand(500, 3, generator=torch.Generator().manual_seed(0))
>>> som = SOM(4, 7, 3, ensemble=2, seed=0).fit(x, mode="batch", epochs=5, progress=False)
>>> som.weight.shape, som.bmu(x).shape
(torch.Size([2, 28, 3]), torch.Size([2, 500]))
"""

from __future__ import annotations

import os
import weakref
from collections.abc import Sequence
from contextlib import nullcontext
from pathlib import Path
from typing import Any

import torch
from torch import nn

from ..config import SOMConfig, TrainConfig
from ..config.options import MODES, ORDERS
from ..validation import check_choice, check_positive, check_positive_int, check_tensor, resolve
from . import checkpoint
from .decay import DECAYS, DecayFn
from .distance import DEFAULT_CHUNK_ELEMENTS, bmu_search, pairwise_sqdist
from .grid import TOPOLOGIES, adjacency, default_sigma, grid_coordinates, grid_sqdist
from .init import INITS, init_pca, init_random, init_sample
from .losses import soft_assign, som_energy
from .metrics import quantization_error, topographic_error, umatrix
from .neighborhood import NEIGHBORHOODS, NeighborhoodFn
from .threads import contended
from .order import Order, Schedules
from .training import Callback, run

_T, _S = TrainConfig, SOMConfig  # the defaults of fit (class attributes), declared once in somtorch.config


def _new_seed() -> int:
    return int.from_bytes(os.urandom(4), "little")


class SOM(nn.Module):
    """An ensemble of ``E`` rectangular or hexagonal self-organising maps.

    Args:
        rows, cols: grid size; ``K = rows * cols`` neurons in row-major order.
        dim: input dimension D.
        ensemble: number of maps E trained together (each with its own seed and hyper-parameters).
        topology: ``"rectangular"`` or ``"hexagonal"`` (offset rows).
        toroidal: wrap the grid on a torus.
        device, dtype: where and in which precision the weights live; inputs must match.
        seed: base seed; member e uses ``seed + e``, so member e of an ensemble equals a solo map
            built with ``seed=seed + e``. ``None`` draws a seed from the OS (kept in ``seeds``).
        seeds: explicit per-member seeds (length E) instead of ``seed``.

    Attributes:
        weight: reference vectors ``(E, K, D)`` (an ``nn.Parameter``; assign a tensor to set it).
        grid: neuron coordinates on the map ``(K, 2)``.
        grid_d2: squared grid distances ``(K, K)``.
        seeds: the members' seeds.
        initialized: whether the weights were set from data, by assignment or by loading.
        skipped: batch map: per epoch of the last :meth:`fit`, the share of samples whose BMU
            search the bounds of :mod:`somtorch.core.bounds` skipped (exact either way).
    """

    def __init__(self, rows: int, cols: int, dim: int, *, ensemble: int = 1, topology: str = "rectangular",
                 toroidal: bool = False, device: str | torch.device | None = None,
                 dtype: torch.dtype = torch.float32, seed: int | None = None,
                 seeds: Sequence[int] | None = None) -> None:
        super().__init__()
        self.rows = check_positive_int("rows", rows)
        self.cols = check_positive_int("cols", cols)
        self.dim = check_positive_int("dim", dim)
        self.ensemble = check_positive_int("ensemble", ensemble)
        self.topology = check_choice("topology", topology, TOPOLOGIES)
        if not isinstance(toroidal, bool):
            raise TypeError(f"toroidal must be a bool; got {type(toroidal).__name__}")
        self.toroidal = toroidal
        if not isinstance(dtype, torch.dtype) or not dtype.is_floating_point:
            raise TypeError(f"dtype must be a floating-point torch.dtype; got {dtype!r}")
        device = torch.device(device) if device is not None else torch.device("cpu")
        if seeds is not None:
            if seed is not None:
                raise ValueError("give either seed or seeds, not both")
            seeds = [int(s) for s in seeds]
            if len(seeds) != self.ensemble:
                raise ValueError(f"seeds must have one entry per member ({self.ensemble}); got {len(seeds)}")
        else:
            if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int)):
                raise TypeError(f"seed must be an int or None; got {type(seed).__name__}")
            base = _new_seed() if seed is None else seed
            seeds = [base + e for e in range(self.ensemble)]
        self.seeds: list[int] = seeds
        self._generators = [torch.Generator(device=device).manual_seed(s) for s in seeds]
        k = self.rows * self.cols
        self.weight = nn.Parameter(torch.zeros(self.ensemble, k, self.dim, device=device, dtype=dtype))
        self.register_buffer("grid", grid_coordinates(self.rows, self.cols, topology, dtype=dtype,
                                                      device=device), persistent=False)
        d2 = grid_sqdist(self.rows, self.cols, topology, toroidal, dtype=dtype, device=device)
        self.register_buffer("grid_d2", d2, persistent=False)
        self.register_buffer("adjacency", adjacency(d2, topology), persistent=False)
        self._fresh = (weakref.ref(self.weight), self.weight._version)  # the untouched zero weights
        self.initialized = False
        self._plan: tuple[int, int] | None = None  # (epochs done, planned) while partial_fit runs
        self._progress: tuple[int, int] = (0, 0)  # of the current partial_fit schedule
        self._order_state: tuple | None = None  # the random order's current epoch, across partial_fit calls
        self.skipped: list[float] = []

    # ------------------------------------------------------------------ basics
    @property
    def initialized(self) -> bool:
        """Whether the weights hold values: set from data, assigned (``som.weight = w``,
        ``som.weight.copy_(w)`` under ``no_grad``, ``load_state_dict``) or loaded. It follows the
        weights themselves (any in-place change or a new tensor counts), not only the setters."""
        ref, version = self._fresh
        return self._initialized or ref() is not self.weight or self.weight._version != version

    @initialized.setter
    def initialized(self, value: bool) -> None:
        self._initialized = bool(value)
        if not value:  # from now on, only a change of the weights marks the map initialised
            self._fresh = (weakref.ref(self.weight), self.weight._version)

    @property
    def num_neurons(self) -> int:
        """K = rows · cols."""
        return self.rows * self.cols

    @property
    def device(self) -> torch.device:
        """The device of the weights."""
        return self.weight.device

    @property
    def dtype(self) -> torch.dtype:
        """The dtype of the weights."""
        return self.weight.dtype

    def __setattr__(self, name: str, value: Any) -> None:
        if name == "weight" and "weight" in self.__dict__.get("_parameters", {}) \
                and not isinstance(value, nn.Parameter):
            self.set_weight(value)
            return
        super().__setattr__(name, value)

    def set_weight(self, value: torch.Tensor) -> SOM:
        """Set the reference vectors; ``(K, D)`` is broadcast to every member, ``(E, K, D)`` is per member."""
        shape = (self.ensemble, self.num_neurons, self.dim)
        check_tensor("weight", value, ndim=(2, 3), floating=True, finite=True)
        if tuple(value.shape[-2:]) != shape[1:] or (value.ndim == 3 and value.shape[0] != self.ensemble):
            raise ValueError(f"weight must have shape {shape} (or {shape[1:]}); got {tuple(value.shape)}")
        with torch.no_grad():
            self.weight.copy_(value.to(self.weight).expand(shape))
        self.initialized = True
        return self

    def config(self) -> dict[str, Any]:
        """Hyper-parameters that rebuild this map (saved with every checkpoint)."""
        return {"rows": self.rows, "cols": self.cols, "dim": self.dim, "ensemble": self.ensemble,
                "topology": self.topology, "toroidal": self.toroidal, "seeds": list(self.seeds),
                "dtype": str(self.dtype).removeprefix("torch.")}

    def extra_repr(self) -> str:
        """The grid, feature count, ensemble size and topology, for ``repr``."""
        return (f"rows={self.rows}, cols={self.cols}, dim={self.dim}, ensemble={self.ensemble}, "
                f"topology={self.topology!r}, toroidal={self.toroidal}")

    def member(self, e: int) -> SOM:
        """A solo map holding a copy of member ``e`` (with that member's seed)."""
        if not 0 <= e < self.ensemble:
            raise IndexError(f"member {e} out of range for an ensemble of {self.ensemble}")
        solo = SOM(self.rows, self.cols, self.dim, topology=self.topology, toroidal=self.toroidal,
                   device=self.device, dtype=self.dtype, seeds=[self.seeds[e]])
        solo.set_weight(self.weight.detach()[e])
        solo.initialized = self.initialized
        return solo

    # ------------------------------------------------------------------ input checks
    def _check_x(self, x: Any, name: str = "x") -> torch.Tensor:
        check_tensor(name, x, ndim=(2, 3), last_dim=self.dim, floating=True, finite=True)
        if x.ndim == 3 and x.shape[0] != self.ensemble:
            raise ValueError(f"{name} of shape {tuple(x.shape)} must have the ensemble size "
                             f"{self.ensemble} as first dimension (or be (N, D), shared by all members)")
        if x.shape[-2] == 0:
            raise ValueError(f"{name} has zero rows; at least one sample is needed")
        if x.dtype != self.dtype:
            raise TypeError(f"{name} has dtype {x.dtype} but the SOM uses {self.dtype}; "
                            f"convert with x.to({self.dtype})")
        if x.device != self.device:
            raise ValueError(f"{name} is on {x.device} but the SOM is on {self.device}; move one of them")
        return x

    def _per_member(self, name: str, value: Any) -> torch.Tensor:
        if isinstance(value, torch.Tensor):
            if value.ndim == 0:
                value = value.reshape(1)
            if value.ndim != 1 or value.shape[0] not in (1, self.ensemble):
                raise ValueError(f"{name} must be a scalar or a tensor of shape [{self.ensemble}] "
                                 f"(one value per member); got shape {tuple(value.shape)}")
        check_positive(name, value)
        t = torch.as_tensor(value, dtype=self.dtype, device=self.device).reshape(-1)
        return t.expand(self.ensemble).clone()

    def _per_member_fn(self, name: str, value: Any, registry: dict) -> list:
        if isinstance(value, (list, tuple)):
            if len(value) != self.ensemble:
                raise ValueError(f"{name} as a sequence needs one entry per member ({self.ensemble}); "
                                 f"got {len(value)}")
            return [resolve(name, v, registry) for v in value]
        return [resolve(name, value, registry)] * self.ensemble

    # ------------------------------------------------------------------ initialisation
    @torch.no_grad()
    def initialize(self, x: torch.Tensor, method: str = "random") -> SOM:
        """Initialise the weights from data: ``"random"``, ``"sample"`` or ``"pca"`` (see ``init``)."""
        x = self._check_x(x)
        check_choice("method", method, INITS)
        members = []
        bounds = (x.amin(0), x.amax(0)) if x.ndim == 2 else None  # shared data: once, not per member
        for e in range(self.ensemble):
            xe = x if x.ndim == 2 else x[e]
            if method == "pca":
                if self.dim < 2:
                    raise ValueError("method='pca' needs at least 2 features; got dim=1")
                members.append(init_pca(xe, self.rows, self.cols))
            elif method == "sample":
                members.append(init_sample(xe, self.num_neurons, self._generators[e]))
            else:
                members.append(init_random(xe, self.num_neurons, self._generators[e],
                                           bounds=bounds if x.ndim == 2 else None))
        return self.set_weight(torch.stack(members))

    # ------------------------------------------------------------------ training
    def fit(self, x: torch.Tensor, *, mode: str = _T.mode, epochs: int | None = None,
            iterations: int | None = None, lr: float | torch.Tensor = _T.lr,
            sigma: float | torch.Tensor | None = None, lr_final: float | torch.Tensor | None = None,
            sigma_final: float | torch.Tensor | None = None,
            lr_decay: str | DecayFn | Sequence[str] = _T.lr_decay,
            sigma_decay: str | DecayFn | Sequence[str] = _T.sigma_decay,
            neighborhood: str | NeighborhoodFn = _T.neighborhood,
            order: str | torch.Tensor = _T.order, batch_size: int = _T.batch_size, init: str = _S.init,
            progress: bool = True, callback: Callback | None = None,
            callback_every: int | None = None) -> SOM:
        """Train the maps on ``x`` and return ``self``.

        The defaults of every argument are those of :class:`~somtorch.config.TrainConfig`
        (``mode`` batch), so ``fit(x)`` trains as ``somtorch-run`` does.

        Args:
            x: samples ``(N, D)`` shared by all members, or ``(E, N, D)``.
            mode: ``"online"`` (Kohonen's sequential rule, one sample per step), ``"batch"`` (batch
                map, one step per epoch) or ``"minibatch"`` (batch-map updates on ``batch_size``
                samples with learning rate ``lr``).
            epochs: passes over the data (default :class:`~somtorch.config.TrainConfig` ``epochs``).
            iterations: online only: number of single-sample steps (overrides ``epochs``).
            lr, sigma: initial learning rate and neighbourhood radius (grid units, default
                max(rows, cols)/2); scalars or per-member tensors ``(E,)``. ``lr`` is unused in batch mode.
            lr_final, sigma_final: end values for the linear / exponential / inverse-time decays
                (default lr/100 and min(sigma, 0.5)); scalar or ``(E,)``.
            lr_decay, sigma_decay: a name from ``somtorch.core.decay.DECAYS``, a callable, or one
                name per member.
            neighborhood: a name from ``somtorch.core.neighborhood.NEIGHBORHOODS`` or a callable.
            order: ``"sequential"``, ``"random"`` (a fresh permutation per epoch and member) or an
                explicit index tensor ``(T,)`` or ``(E, T)`` (online: T = iterations; minibatch:
                T = steps · batch_size).
            batch_size: mini-batch size.
            init: initialisation used if the weights were not initialised yet.
            progress: show a progress bar (only appears for runs longer than half a second).
            callback: called with a :class:`~somtorch.core.training.StepInfo` every ``callback_every``
                steps (default: once per epoch) and at the end.
        """
        x = self._check_x(x)
        check_choice("mode", mode, MODES)
        n = x.shape[-2]
        if sigma is None:
            sigma = default_sigma(self.rows, self.cols)
        sigma_t = self._per_member("sigma", sigma)
        lr_t = self._per_member("lr", lr)
        lr_end = self._per_member("lr_final", lr_final) if lr_final is not None else lr_t / 100.0
        sig_end = (self._per_member("sigma_final", sigma_final) if sigma_final is not None
                   else torch.clamp(sigma_t, max=0.5))
        sched = Schedules(lr_t, lr_end, self._per_member_fn("lr_decay", lr_decay, DECAYS),
                          sigma_t, sig_end, self._per_member_fn("sigma_decay", sigma_decay, DECAYS))
        nb = resolve("neighborhood", neighborhood, NEIGHBORHOODS)
        batch_size = check_positive_int("batch_size", batch_size)
        if iterations is not None and mode != "online":
            raise ValueError(f"iterations is only for mode='online'; use epochs for mode={mode!r}")
        epochs = check_positive_int("epochs", epochs if epochs is not None else _T.epochs)
        if mode == "online":
            steps = check_positive_int("iterations", iterations) if iterations is not None else epochs * n
            stream = steps
        elif mode == "batch":
            steps, stream = epochs, 0
        else:
            steps = max(1, epochs * n // batch_size)
            stream = steps * batch_size
        offset, total = 0, None
        if self._plan is not None:  # partial_fit: these epochs continue a longer schedule
            done, planned = self._plan
            per = {"online": n, "batch": 1}.get(mode)
            if per is None:  # minibatch: the steps of the first k epochs, as fit counts them
                offset, total = done * n // batch_size, max(1, planned * n // batch_size)
                steps = max(1, (done + epochs) * n // batch_size - offset)
            else:
                offset, total, steps = done * per, planned * per, epochs * per
            stream = steps * (batch_size if mode == "minibatch" else 1) if mode != "batch" else 0
        if isinstance(order, torch.Tensor):
            if mode == "batch":
                raise ValueError("an explicit order has no meaning in mode='batch' (every step uses all samples)")
            check_tensor("order", order, ndim=(1, 2))
            if order.dtype not in (torch.int64, torch.int32):
                raise TypeError(f"order must be an integer index tensor; got dtype {order.dtype}")
            if order.shape[-1] != stream or (order.ndim == 2 and order.shape[0] != self.ensemble):
                raise ValueError(f"order must have shape ({stream},) or ({self.ensemble}, {stream}) for "
                                 f"mode={mode!r} with these settings; got {tuple(order.shape)}")
            if int(order.min()) < 0 or int(order.max()) >= n:
                raise ValueError(f"order holds indices outside [0, {n}); got min {int(order.min())}, "
                                 f"max {int(order.max())}")
            stream_order = Order("explicit", n, self.ensemble, self._generators, self.device,
                                 explicit=order.to(self.device, torch.long))
        else:
            check_choice("order", order, ORDERS)
            stream_order = Order(order, n, self.ensemble, self._generators, self.device)
        check_choice("init", init, INITS)
        if callback_every is not None:
            check_positive_int("callback_every", callback_every)
        if callback is not None and not callable(callback):
            raise TypeError(f"callback must be callable; got {type(callback).__name__}")
        # ---- all checks done: work starts here
        if self._plan is None:
            self._progress = (0, 0)  # a plain fit is a schedule of its own
        if not self.initialized:
            self.initialize(x, init)
        cached = self._order_state if self._plan is not None else None
        if cached is not None and cached[0] == (stream_order.kind, n):  # a mini-batch epoch split across calls
            stream_order._epoch, stream_order._perm = cached[1], cached[2]
        # on a busy CPU: no more torch threads than the cores other processes leave free (same bits)
        with contended() if self.weight.device.type == "cpu" else nullcontext():
            self.skipped = run(self.weight.data, x, mode=mode, steps=steps, batch_size=batch_size,
                               order=stream_order, sched=sched, grid_d2=self.grid_d2, neighborhood=nb,
                               progress=progress, callback=callback, callback_every=callback_every,
                               desc=f"SOM {mode}", offset=offset, total=total)
        self._order_state = ((stream_order.kind, n), stream_order._epoch, stream_order._perm) \
            if self._plan is not None else None
        return self

    def partial_fit(self, x: torch.Tensor, *, total_epochs: int, epochs: int = 1, **kwargs: Any) -> SOM:
        """Train ``epochs`` more epochs on ``x`` as part of one schedule of ``total_epochs``.

        The decay of the learning rate and the radius continues where the previous call stopped
        instead of restarting (MiniSom users ask for this, minisom#83): ``k`` calls of
        ``partial_fit(x, total_epochs=k)`` give the weights of ``fit(x, epochs=k)`` bitwise for
        the same ``x``. ``x`` may change between calls (a stream of chunks: progress is counted
        in epochs of the data at hand). The other keyword arguments are those of :meth:`fit` and
        must stay the same within one schedule; :attr:`epochs_done` says how far it got. A call
        of :meth:`fit`, or a different ``total_epochs`` after the schedule ended, starts a new one.
        Random orders draw from the members' generators, so they continue as well.

        Raises:
            ValueError: ``epochs`` would run past ``total_epochs``, or ``total_epochs`` changed
                in the middle of a schedule.
        """
        total_epochs = check_positive_int("total_epochs", total_epochs)
        epochs = check_positive_int("epochs", epochs)
        if "iterations" in kwargs:
            raise ValueError("partial_fit counts epochs; iterations is for fit(mode='online')")
        done, planned = self._progress
        if planned != total_epochs or done >= planned:
            if 0 < done < planned:
                raise ValueError(f"a schedule of {planned} epochs is at epoch {done}; total_epochs={total_epochs} "
                                 "would change it (call fit to start over)")
            done, planned = 0, total_epochs
        if done + epochs > planned:
            raise ValueError(f"epoch {done} + {epochs} would run past total_epochs={planned}")
        self._plan = (done, planned)
        try:
            self.fit(x, epochs=epochs, **kwargs)
        finally:
            self._plan = None
        self._progress = (done + epochs, planned)
        return self

    @property
    def epochs_done(self) -> int:
        """Epochs of the current :meth:`partial_fit` schedule trained so far (0 after :meth:`fit`)."""
        return self._progress[0]

    # ------------------------------------------------------------------ inference and metrics
    def bmu(self, x: torch.Tensor, *, chunk_elements: int = DEFAULT_CHUNK_ELEMENTS) -> torch.Tensor:
        """Best-matching unit of every sample, per member. ``(N, D)``/``(E, N, D)`` → ``(E, N)`` long."""
        return bmu_search(self._check_x(x), self.weight.detach(), chunk_elements=chunk_elements)

    def quantization_error(self, x: torch.Tensor) -> torch.Tensor:
        """Mean distance of the samples to their BMU, per member ``(E,)``."""
        return quantization_error(self._check_x(x), self.weight.detach())

    def topographic_error(self, x: torch.Tensor) -> torch.Tensor:
        """Share of samples whose two best units are not adjacent, per member ``(E,)``."""
        return topographic_error(self._check_x(x), self.weight.detach(), self.adjacency)

    def umatrix(self) -> torch.Tensor:
        """Mean distance of each neuron to its grid neighbours ``(E, rows, cols)``."""
        return umatrix(self.weight.detach(), self.adjacency, self.rows, self.cols)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Squared distances of every sample to every neuron (differentiable) ``(E, N, K)``."""
        return pairwise_sqdist(self._check_x(x), self.weight)

    def soft_assign(self, x: torch.Tensor, temperature: float | torch.Tensor = 1.0) -> torch.Tensor:
        """Differentiable soft BMU weights ``softmax(−‖x − w‖²/τ)`` ``(E, N, K)``."""
        tau = self._per_member("temperature", temperature)
        return soft_assign(self._check_x(x), self.weight, tau)

    def loss(self, x: torch.Tensor, sigma: float | torch.Tensor = 1.0,
             neighborhood: str | NeighborhoodFn = "gaussian") -> torch.Tensor:
        """SOM energy per member ``(E,)`` (see :func:`somtorch.core.losses.som_energy`)."""
        sig = self._per_member("sigma", sigma)
        nb = resolve("neighborhood", neighborhood, NEIGHBORHOODS)
        return som_energy(self._check_x(x), self.weight, self.grid_d2, sig, nb)

    # ------------------------------------------------------------------ persistence
    def save(self, path: str | os.PathLike) -> Path:
        """Write the weights (safetensors) and hyper-parameters (``<path>.json``) atomically."""
        return checkpoint.save(self, path)

    @classmethod
    def from_config(cls, cfg: SOMConfig, dim: int, *, ensemble: int = 1, seed: int = 0,
                    device: str | torch.device | None = None) -> SOM:
        """The untrained maps a :class:`~somtorch.config.SOMConfig` describes (``init`` is applied
        by :meth:`fit`); ``SOM.load`` reads the same hyper-parameters back from a checkpoint."""
        return cls(cfg.rows, cfg.cols, dim, ensemble=ensemble, topology=cfg.topology, toroidal=cfg.toroidal,
                   seed=seed, device=device)

    @classmethod
    def load(cls, path: str | os.PathLike, *, device: str | torch.device | None = None) -> SOM:
        """Rebuild a map saved with :meth:`save`."""
        return checkpoint.load(cls, path, device=device)
