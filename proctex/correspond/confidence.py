"""How far to trust the cage teacher, point by point, without ground truth: agreement with the
teacher's maps of the group's neighbouring shapes.

A cage pair maps a shape's part onto the template part. Two shapes that look alike (their parts
nearly coincide in the representative's normalised frame) should be mapped alike: a point of one
and the nearest point of the other land close together on the template. Where a pair's map
disagrees with the maps of its nearest shapes, around the 3-cycle *shape -> neighbour (nearest
point) -> template* against *shape -> template*, the teacher was unsure there: a cage that
twisted, a thin wall's sides swapped, a symmetric part turned the other way on one shape only.
:func:`neighbour_disagreement` measures that per point; :func:`confidence_weights` turns it into
the weights :func:`proctex.correspond.training.train` scales each point's loss by, so a student
learns the teacher where the teacher is consistent across the family rather than averaging its
slips. Neighbours are the nearest shapes in procedural parameters where every shape has them
(:func:`param_features`), else by shape (the mean nearest-point distance between the parts'
samples in the common frame).

The disagreement also holds the family's genuine variation between two neighbours, which is small
because they are the nearest shapes; the weights are relative to the group's median, so a group
whose shapes all vary a lot is not down-weighted as a whole.

Measured (``tests/bench/bench_confidence.py``, the build's own train pairs scored against the
ground truth the build never sees): the disagreement points at the teacher's errors on the fork,
the chair, the desk and the sofa (rank correlation 0.22-0.51 per point, 0.44-0.68 per pair) and
hardly on the mug, the mushroom, the vase or the cake (0.03-0.14 per point); the teacher's error
as the weighted loss sees it falls from 0.0108 to 0.0080 on the fork, 0.0077 to 0.0071 on the
chair, 0.0051 to 0.0048 on the sofa. A student trained with the weights did not gain from them (the fork at the default
scale: GT mean 0.0068 -> 0.0074, variance 0.0042 -> 0.0040), so training does not use them by
default (:attr:`proctex.correspond.corrnet.CorrNetConfig.confidence`).
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
from scipy.spatial import cKDTree

#: Smallest disagreement scale (normalised units): below it two maps are the same for any texture
#: (a thousandth of the part's radius), so exact families keep weights near 1.
MIN_SCALE = 1e-3


def _pair_arrays(pairs: Sequence[tuple[np.ndarray, np.ndarray]]) -> list[tuple[np.ndarray, np.ndarray]]:
    out = []
    for i, p in enumerate(pairs):
        if not isinstance(p, (tuple, list)) or len(p) != 2:
            raise ValueError(f"pairs[{i}]: expected a (src, dst) pair")
        src, dst = (np.asarray(a, dtype=np.float64) for a in p)
        if src.ndim != 2 or src.shape[1] != 3 or src.shape != dst.shape or len(src) == 0:
            raise ValueError(f"pairs[{i}]: src and dst must be the same non-empty (n, 3), got {src.shape} and {dst.shape}")
        if not (np.isfinite(src).all() and np.isfinite(dst).all()):
            raise ValueError(f"pairs[{i}]: src and dst must be finite")
        out.append((src, dst))
    return out


def param_features(params: Sequence[dict[str, Any]]) -> np.ndarray | None:
    """``(m, p)`` float64 features of ``m`` shapes' procedural parameters for finding neighbours:
    numbers as they are, booleans as 0 / 1, anything else one-hot per value; each column divided
    by its spread (constant columns dropped), so every parameter counts alike. ``None`` where the
    shapes do not all carry the same non-empty set of parameters (a folder of meshes without
    them) or a number is not finite."""
    if not params or any(not isinstance(p, dict) or not p for p in params):
        return None
    keys = sorted(params[0])
    if any(sorted(p) != keys for p in params):
        return None
    cols = []
    for key in keys:
        vals = [p[key] for p in params]
        if all(isinstance(v, (bool, np.bool_)) for v in vals):
            cols.append(np.array(vals, dtype=np.float64)[:, None])
        elif all(isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_)) for v in vals):
            col = np.array(vals, dtype=np.float64)
            if not np.isfinite(col).all():
                return None
            cols.append(col[:, None])
        else:
            labels = [repr(v) for v in vals]
            cols.append(np.array([[lab == u for u in sorted(set(labels))] for lab in labels], dtype=np.float64))
    x = np.hstack(cols)
    spread = x.std(axis=0)
    keep = spread > 1e-12
    return (x[:, keep] - x[:, keep].mean(axis=0)) / spread[keep]


def neighbour_disagreement(pairs: Sequence[tuple[np.ndarray, np.ndarray]], k: int = 3, probe: int = 256, seed: int = 0, features: np.ndarray | None = None) -> list[np.ndarray]:
    """Per pair, per source point, how far its teacher target lies from the targets the ``k``
    nearest other shapes' teachers give the nearest point of their part.

    Args:
        pairs: one group's cage pairs ``(src (n_i, 3), dst (n_i, 3))``: source samples in the
            representative's normalised frame and their template points.
        k: neighbours per pair (fewer when the group has fewer other pairs); the per-point result
            is the median over them, so one odd neighbour does not count.
        probe: source samples per pair (seeded) that rank the neighbours by shape.
        features: ``(m, p)`` per pair, e.g. :func:`param_features` of the shapes' procedural
            parameters: neighbours are then the nearest in these (Euclidean), not by shape.
            Measured (``tests/bench/bench_confidence.py``), parameter neighbours point at the
            teacher's errors better than shape neighbours where a family has parameters.
    Returns:
        ``[(n_i,) float64]``: zeros for a group of one pair (nothing to compare with).
    """
    data = _pair_arrays(pairs)
    if not (isinstance(k, (int, np.integer)) and k >= 1):
        raise ValueError(f"k must be a positive integer, got {k!r}")
    if not (isinstance(probe, (int, np.integer)) and probe >= 1):
        raise ValueError(f"probe must be a positive integer, got {probe!r}")
    m = len(data)
    if features is not None:
        features = np.asarray(features, dtype=np.float64)
        if features.ndim != 2 or len(features) != m or not np.isfinite(features).all():
            raise ValueError(f"features must be a finite (m, p) array with one row per pair ({m}), got shape {features.shape}")
    if m < 2:
        return [np.zeros(len(src)) for src, _ in data]
    trees = [cKDTree(src) for src, _ in data]
    if features is not None:
        dist = np.linalg.norm(features[:, None] - features[None], axis=2)
        np.fill_diagonal(dist, np.inf)
    else:
        rng = np.random.default_rng(seed)
        probes = [src[rng.choice(len(src), size=min(probe, len(src)), replace=False)] for src, _ in data]
        # Shape distance: the mean nearest-point distance of one part's probe to the other's samples, both ways.
        dist = np.full((m, m), np.inf)
        for i in range(m):
            for j in range(i + 1, m):
                d = trees[j].query(probes[i])[0].mean() + trees[i].query(probes[j])[0].mean()
                dist[i, j] = dist[j, i] = d
    out = []
    kk = min(int(k), m - 1)
    for i, (src, dst) in enumerate(data):
        near = np.argsort(dist[i], kind="stable")[:kk]
        gaps = [np.linalg.norm(dst - data[j][1][trees[j].query(src)[1]], axis=1) for j in near]
        out.append(np.median(np.stack(gaps), axis=0))
    return out


def confidence_weights(disagreement: Sequence[np.ndarray], scale: float = 1.0) -> list[np.ndarray]:
    """Loss weights ``1 / (1 + (d / s)^2)`` in (0, 1] from :func:`neighbour_disagreement`'s ``d``,
    with ``s = scale`` times the median over every point of the group (at least
    :data:`MIN_SCALE`): a point disagreeing as much as the group's typical point weighs 1/2 (with
    ``scale`` 1), one disagreeing 3x as much 1/10. Returns ``[(n_i,) float32]``."""
    if not (isinstance(scale, (int, float)) and np.isfinite(scale) and scale > 0):
        raise ValueError(f"scale must be a positive number, got {scale!r}")
    ds = [np.asarray(d, dtype=np.float64) for d in disagreement]
    if not ds:
        return []
    if any(d.ndim != 1 or not np.isfinite(d).all() or (d < 0).any() for d in ds):
        raise ValueError("disagreements must be finite non-negative (n,) arrays")
    s = max(float(scale) * float(np.median(np.concatenate(ds))), MIN_SCALE)
    return [(1.0 / (1.0 + (d / s) ** 2)).astype(np.float32) for d in ds]
