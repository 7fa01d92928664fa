"""Consensus of several maps per run (``PipelineConfig.consensus``): each run trains ``K`` maps with
seeds of its own, runs the object step on each, and keeps the map whose reduced map agrees best
with the others' — the medoid under the intersection over union of the pixels each keeps.

A SOM's result on one frame depends on its seed: on the development corpus a frame the defaults
get right in most runs still loses some of them to a map that chained the object to its
neighbours, or split it. Those losing maps rarely agree with each other, while the maps that find
the object keep nearly the same pixels; the medoid of several maps therefore follows the majority
where there is one, and costs ``K`` trainings and object steps per run (each some milliseconds to a
few tens of them on a 640 × 480 map: docs/validation_log.md, session 34).

Map ``k`` of the run seeded ``s`` is seeded ``(s + k · SEED_STRIDE) mod 2³²`` (torch's CPU generator
reads 32 bits of a seed; map 0 is the run's own seed: ``consensus=1`` is the plain pipeline, bit for
bit). ``SEED_STRIDE`` is the 32-bit golden-ratio constant, so the first eight maps of runs seeded
below 2²⁰ never share a seed, and the chosen map alone, trained with its own seed, reproduces the
run's result.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import torch

from .core import SOM

__all__ = ["SEED_STRIDE", "agreement", "choose", "compact", "medoid", "merge_runs", "pair_counts", "shifted"]

SEED_STRIDE = 0x9E3779B9  # map k of the run seeded s: (s + k * SEED_STRIDE) mod 2**32


def shifted(cfg: Any, k: int) -> Any:
    """``cfg`` with the seeds of map ``k`` of every run (``(seed + k · SEED_STRIDE) mod 2³²``)."""
    return cfg if k == 0 else replace(cfg, seed=(cfg.seed + k * SEED_STRIDE) % 2 ** 32)


def agreement(masks: torch.Tensor) -> torch.Tensor:
    """Pairwise intersection over union ``(K, K)`` of ``K`` boolean masks (any shape after the
    first dimension); two empty masks agree fully. The pixel counts are exact integers however they
    are taken (:func:`pair_counts` for boolean masks on the CPU, else a float64 product of 0/1
    values, exact below 2⁵³ pixels): the same IoUs either way."""
    if masks.dtype == torch.bool and masks.device.type == "cpu":
        inter = pair_counts(masks).to(torch.float64)
    else:
        m = masks.reshape(masks.shape[0], -1).to(torch.float64)
        inter = m @ m.T
    area = inter.diagonal()
    union = area[:, None] + area[None, :] - inter
    return torch.where(union > 0, inter / union.clamp(min=1), torch.ones_like(inter))


_POPCOUNT = None  # (256,) uint8: set bits of each byte (numpy < 2 has no bitwise_count)


def pair_counts(masks: torch.Tensor) -> torch.Tensor:
    """``(K, K)`` long: the pixels each pair of ``K`` boolean masks shares (its diagonal: each mask's
    own), by a population count of the masks packed 64 pixels to a word — a run's five reduced maps
    of 1264 × 720 in about 0.5 ms instead of 15 for the float product.

    Shape:
        ``masks`` ``(K, ...)`` bool on the CPU.
    """
    import numpy as np

    global _POPCOUNT
    k = masks.shape[0]
    packed = np.packbits(masks.reshape(k, -1).numpy(), axis=1)
    packed = np.pad(packed, ((0, 0), (0, -packed.shape[1] % 8))).view(np.uint64)
    if hasattr(np, "bitwise_count"):
        count = lambda w: int(np.bitwise_count(w).sum(dtype=np.int64))  # noqa: E731
    else:
        if _POPCOUNT is None:
            _POPCOUNT = np.array([bin(i).count("1") for i in range(256)], dtype=np.uint8)
        count = lambda w: int(_POPCOUNT[w.view(np.uint8)].sum(dtype=np.int64))  # noqa: E731
    out = torch.empty(k, k, dtype=torch.long)
    for i in range(k):
        for j in range(i, k):
            out[i, j] = out[j, i] = count(packed[i] & packed[j])
    return out


def medoid(masks: torch.Tensor) -> tuple[int, float]:
    """The index of the mask agreeing best with the others (largest summed IoU; ties: the first)
    and its mean IoU with the others (1.0 for a single mask)."""
    k = masks.shape[0]
    if k == 1:
        return 0, 1.0
    iou = agreement(masks)
    total = iou.sum(1) - 1.0  # without each mask's agreement with itself
    best = int(torch.argmax(total))  # the first of equal totals
    return best, float(total[best]) / (k - 1)


def compact(seg: Any) -> Any:
    """``seg`` with its label maps as int16 where its segments fit (a map waiting for the consensus:
    ``E`` int64 label maps per map of the run would hold 4 times the memory)."""
    small = seg.labels.dtype != torch.int16 and int(seg.labels.max()) < 2 ** 15
    return replace(seg, labels=seg.labels.to(torch.int16)) if small else seg


def merge_runs(segs: list[Any], chosen: list[int]) -> Any:
    """One :class:`~somtorch.segmenters.Segmentation` of ``E`` runs from ``K`` segmentations of
    ``E`` members each: run ``e`` takes member ``e`` of ``segs[chosen[e]]`` (labels, as int64 whatever
    they were held as, reference disparities, prototypes, seed and, for a SOM, its weights)."""
    first = segs[0]
    runs = range(len(chosen))
    pick = lambda t: torch.stack([getattr(segs[k], t)[e] for e, k in zip(runs, chosen)])  # noqa: E731
    labels = torch.empty((len(chosen), *first.labels.shape[1:]), dtype=torch.long)  # int64, filled in place
    for e, k in zip(runs, chosen):
        labels[e] = segs[k].labels[e]
    som = None
    if first.som is not None:
        s0 = first.som
        seeds = [segs[k].som.seeds[e] for e, k in zip(runs, chosen)]
        som = SOM(s0.rows, s0.cols, s0.dim, ensemble=len(chosen), topology=s0.topology, toroidal=s0.toroidal,
                  device=s0.device, dtype=s0.dtype, seeds=seeds)
        som.set_weight(torch.stack([segs[k].som.weight.detach()[e] for e, k in zip(runs, chosen)]))
        som.initialized = True
    return replace(first, labels=labels, ref_disparity=pick("ref_disparity"),
                   prototypes=pick("prototypes") if first.prototypes is not None else None, som=som,
                   seeds=[segs[k].seeds[e] for e, k in zip(runs, chosen)])


def choose(per_map: list[list[Any]]) -> tuple[list[int], list[Any]]:
    """For every run, the map of ``per_map`` (``K`` lists of ``E``
    :class:`~somtorch.results.MemberResult`) whose reduced map is the medoid (:func:`medoid`);
    returns the chosen map per run and its member results, each carrying the run's seed (that of its
    map 0), ``consensus_map`` (the chosen map's index), ``agreement`` (its mean IoU with the other
    maps' kept pixels) and, on a scored scene, ``maps_useful`` (how many of the run's maps were useful)."""
    chosen, members = [], []
    for e in range(len(per_map[0])):
        k, agree = medoid(torch.stack([m[e].reduction.mask for m in per_map]))
        chosen.append(k)
        scores = [m[e].score for m in per_map]
        useful = sum(s.useful_hit for s in scores) if all(s is not None for s in scores) else None
        members.append(replace(per_map[k][e], seed=per_map[0][e].seed, consensus_map=k, agreement=agree,
                               maps_useful=useful))
    return chosen, members
