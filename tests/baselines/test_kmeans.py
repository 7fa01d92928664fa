"""k-means baseline: ensemble = solo runs, determinism, Lloyd's monotonicity, a numpy oracle, errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from somtorch.baselines import KMeansResult, kmeans, kmeans_init

BLOB_MEANS = np.array([[0.0, 0.0], [5.0, 5.0], [0.0, 5.0]])


def three_blobs(n_per_blob: int = 300, std: float = 0.2, seed: int = 0) -> torch.Tensor:
    """Three well-separated 2-D Gaussian blobs ``(3·n_per_blob, 2)`` float32, blob means BLOB_MEANS."""
    rng = np.random.RandomState(seed)
    pts = np.vstack([m + std * rng.randn(n_per_blob, 2) for m in BLOB_MEANS])
    return torch.from_numpy(pts).float()


@pytest.fixture(scope="module")
def x() -> torch.Tensor:
    """2,000 uniform 3-D points: no cluster structure, so Lloyd needs many iterations."""
    return torch.rand(2000, 3, generator=torch.Generator().manual_seed(1))


def numpy_lloyd(x: np.ndarray, centers: np.ndarray, iterations: int) -> tuple[np.ndarray, float, int]:
    """Textbook Lloyd in float64: stop when no label changes; empty clusters keep their centre."""
    c = centers.astype(np.float64).copy()
    prev = None
    done = 0
    for _ in range(iterations):
        d2 = ((x[:, None, :] - c[None]) ** 2).sum(-1)  # (N, K)
        labels = d2.argmin(1)
        if prev is not None and np.array_equal(labels, prev):
            break
        for j in range(c.shape[0]):
            members = x[labels == j]
            if len(members):
                c[j] = members.mean(0)
        prev = labels
        done += 1
    d2 = ((x[:, None, :] - c[None]) ** 2).sum(-1)
    return c, float(d2.min(1).sum()), done


@pytest.mark.parametrize("init", ["kmeans++", "sample"])
def test_member_equals_solo_run_bitwise(x, init):
    ens = kmeans(x, 7, ensemble=4, seed=10, iterations=30, init=init)
    assert isinstance(ens, KMeansResult)
    assert ens.centers.shape == (4, 7, 3) and ens.centers.dtype == torch.float32
    assert ens.inertia.shape == (4,) and ens.inertia.dtype == torch.float64
    solo_iters = []
    for e in range(4):
        solo = kmeans(x, 7, ensemble=1, seed=10 + e, iterations=30, init=init)
        assert torch.equal(ens.centers[e], solo.centers[0])
        assert torch.equal(ens.inertia[e], solo.inertia[0])
        solo_iters.append(solo.iterations)
    assert ens.iterations == max(solo_iters)
    assert len({tuple(c.flatten().tolist()) for c in ens.centers}) == 4  # the seeds really differ


def test_member_equals_solo_run_with_tol(x):
    """With tol > 0 members stop at different iterations; the early ones must stay frozen."""
    ens = kmeans(x, 7, ensemble=3, seed=0, iterations=30, tol=1e-3)
    for e in range(3):
        assert torch.equal(ens.centers[e], kmeans(x, 7, seed=e, iterations=30, tol=1e-3).centers[0])


def test_same_seed_same_result_and_chunking_does_not_matter(x):
    a = kmeans(x, 5, ensemble=2, seed=3)
    b = kmeans(x, 5, ensemble=2, seed=3)
    c = kmeans(x, 5, ensemble=2, seed=3, chunk_size=333)
    assert torch.equal(a.centers, b.centers) and torch.equal(a.inertia, b.inertia)
    assert torch.equal(a.centers, c.centers) and torch.equal(a.inertia, c.inertia)
    assert a.iterations == b.iterations == c.iterations


def test_inertia_never_increases_with_more_iterations(x):
    runs = [kmeans(x, 8, ensemble=3, seed=2, iterations=t) for t in (1, 2, 5, 10)]
    inertia = torch.stack([r.inertia for r in runs])  # (4, E)
    assert bool((inertia[1:] <= inertia[:-1] * (1 + 1e-12)).all())
    assert bool((inertia[-1] < inertia[0]).all())  # and it does improve
    assert [r.iterations for r in runs] == [1, 2, 5, 10]  # uniform data: no early convergence yet


def test_recovers_three_blob_means():
    pts = three_blobs()
    res = kmeans(pts, 3, ensemble=5, seed=0)
    assert res.iterations < 20  # converged: an assignment step changed nothing
    for c in res.centers:
        got = c.double().numpy()
        got = got[np.lexsort((got[:, 1], got[:, 0]))]
        want = BLOB_MEANS[np.lexsort((BLOB_MEANS[:, 1], BLOB_MEANS[:, 0]))]
        np.testing.assert_allclose(got, want, rtol=0, atol=0.05)
    assert torch.allclose(res.inertia, res.inertia[0].expand(5))  # every seed finds the same optimum


@pytest.mark.parametrize("init", ["kmeans++", "sample"])
def test_matches_numpy_lloyd_from_the_same_start(x, init):
    xd = x.double()
    c0 = kmeans_init(xd, 6, torch.Generator().manual_seed(4), init)
    ours = kmeans(xd, 6, init=c0, iterations=15)
    # kmeans(seed=s) starts from kmeans_init with a generator seeded s
    assert torch.equal(ours.centers, kmeans(xd, 6, seed=4, init=init, iterations=15).centers)
    want, inertia, done = numpy_lloyd(xd.numpy(), c0.numpy(), 15)
    np.testing.assert_allclose(ours.centers[0].numpy(), want, rtol=0, atol=1e-5)
    assert float(ours.inertia[0]) == pytest.approx(inertia, rel=1e-10)
    assert ours.iterations == done


def test_numpy_lloyd_to_convergence_and_empty_cluster_keeps_its_centre():
    pts = three_blobs(n_per_blob=100).double()
    far = torch.tensor([[100.0, -100.0]], dtype=torch.float64)
    c0 = torch.cat([pts[[0, 150, 299]], far])  # (4, 2): the far centre never wins a sample
    ours = kmeans(pts, 4, init=c0, iterations=50)
    want, inertia, done = numpy_lloyd(pts.numpy(), c0.numpy(), 50)
    assert done < 50 and ours.iterations == done
    np.testing.assert_allclose(ours.centers[0].numpy(), want, rtol=0, atol=1e-12)
    assert torch.equal(ours.centers[0, 3], far[0])
    assert float(ours.inertia[0]) == pytest.approx(inertia, rel=1e-12)


def test_init_tensor_shared_or_per_member(x):
    c0 = torch.stack([kmeans_init(x, 4, torch.Generator().manual_seed(s), "sample") for s in (7, 8)])
    per_member = kmeans(x, 4, ensemble=2, init=c0)
    assert torch.equal(per_member.centers, kmeans(x, 4, ensemble=2, seed=7, init="sample").centers)
    shared = kmeans(x, 4, ensemble=2, init=c0[0])
    assert torch.equal(shared.centers[0], shared.centers[1])


def test_kmeanspp_draws_distinct_points_and_k_equals_n():
    pts = torch.tensor([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [5.0, 5.0]])
    c = kmeans_init(pts, 4, torch.Generator().manual_seed(0))
    assert sorted(map(tuple, c.tolist())) == sorted(map(tuple, pts.tolist()))
    res = kmeans(pts, 4)
    assert float(res.inertia[0]) == 0.0


BAD = [
    (dict(x=[[0.0, 1.0]]), TypeError, "x must be a torch.Tensor"),
    (dict(x=torch.zeros(10)), ValueError, "x must have 2 dimensions"),
    (dict(x=torch.zeros(10, 2, dtype=torch.long)), TypeError, "x must be a floating-point"),
    (dict(x=torch.zeros(10, 2, dtype=torch.float16)), TypeError, "x must be float32 or float64"),
    (dict(x=torch.tensor([[0.0, float("nan")]] * 5)), ValueError, "x contains 5 non-finite"),
    (dict(x=torch.zeros(0, 2)), ValueError, "x is empty"),
    (dict(k=11), ValueError, "k=11 clusters need at least k samples"),
    (dict(k=0), ValueError, "k must be a positive integer"),
    (dict(k=2.0), TypeError, "k must be a positive integer"),
    (dict(ensemble=0), ValueError, "ensemble must be a positive integer"),
    (dict(iterations=0), ValueError, "iterations must be a positive integer"),
    (dict(seed=-1), ValueError, "seed must be >= 0"),
    (dict(seed=1.5), TypeError, "seed must be an int"),
    (dict(init="random"), ValueError, "init='random' is not known; valid names: kmeans\\+\\+, sample"),
    (dict(init=torch.zeros(3, 2)), ValueError, "init as a tensor must have shape"),
    (dict(init=torch.zeros(2, 2, dtype=torch.float64)), TypeError, "init must have the dtype"),
    (dict(tol=-1.0), ValueError, "tol must be finite and >= 0"),
    (dict(chunk_size=0), ValueError, "chunk_size must be a positive integer"),
]


@pytest.mark.parametrize("kwargs,err,msg", BAD, ids=[str(i) for i in range(len(BAD))])
def test_bad_input_names_the_argument(kwargs, err, msg):
    args = dict(x=torch.rand(10, 2), k=2)
    args.update(kwargs)
    with pytest.raises(err, match=msg):
        kmeans(args.pop("x"), args.pop("k"), **args)


def test_kmeans_init_checks_its_generator():
    with pytest.raises(TypeError, match="generator must be a torch.Generator"):
        kmeans_init(torch.rand(5, 2), 2, 0)
    with pytest.raises(ValueError, match="init='pca' is not known"):
        kmeans_init(torch.rand(5, 2), 2, torch.Generator(), "pca")
