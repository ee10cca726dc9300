"""Slow, obviously correct references of :mod:`proctex.texture.inpaint` (loops over points, pixels or
texels), which the tests compare the shipped fast versions with; not used by the library."""

from __future__ import annotations

import numpy as np

from proctex.texture.inpaint import DEFAULT_MIN_SOURCE_SHARE, NNFResult, _penalty, _prepare_nnf_inputs


def patch_distance_reference(
    image: np.ndarray,
    valid: np.ndarray,
    source: np.ndarray,
    labels: np.ndarray,
    target_rc: tuple[int, int],
    source_rc: tuple[int, int],
    patch: int,
    penalty: float,
) -> float:
    """Slow, explicit patch distance (module docstring): a loop over the window.

    A target texel counts if it is inside the image, valid and of the target centre's chart; it costs its
    squared colour difference to the source texel at the same offset if that one is inside the image,
    source and of the source centre's chart, else ``penalty``. Returns the mean per counted texel.
    """
    img = np.asarray(image)
    img = img / 255.0 if img.dtype == np.uint8 else img.astype(np.float64)
    H, W = valid.shape
    r = patch // 2
    lt = labels[target_rc[0], target_rc[1]]
    ls = labels[source_rc[0], source_rc[1]]
    num = 0.0
    den = 0.0
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            ti, tj = target_rc[0] + dy, target_rc[1] + dx
            if not (0 <= ti < H and 0 <= tj < W) or not valid[ti, tj] or labels[ti, tj] != lt:
                continue
            si, sj = source_rc[0] + dy, source_rc[1] + dx
            den += 1.0
            if 0 <= si < H and 0 <= sj < W and source[si, sj] and labels[si, sj] == ls:
                num += float(((img[ti, tj] - img[si, sj]) ** 2).sum())
            else:
                num += penalty
    return num / den if den > 0 else 0.0


def nnf_reference(
    image: np.ndarray,
    valid: np.ndarray,
    source: np.ndarray,
    targets: np.ndarray,
    patch: int = 7,
    min_source_share: float = DEFAULT_MIN_SOURCE_SHARE,
    charts: np.ndarray | None = None,
) -> NNFResult:
    """Brute-force NNF: every target against every valid centre with :func:`patch_distance_reference`.

    Valid centres are counted explicitly too (a source texel with >= ``min_source_share`` of its window
    source of its own chart). Ties go to the first centre in row-major order. Only for tiny images.
    """
    work, valid, source, targets, patch, share, labels = _prepare_nnf_inputs(image, valid, source, targets, patch, min_source_share, charts)
    penalty = _penalty(work, source)
    H, W = valid.shape
    r = patch // 2
    centres = []
    for i, j in np.argwhere(source):
        n = sum(1 for a in range(i - r, i + r + 1) for b in range(j - r, j + r + 1) if 0 <= a < H and 0 <= b < W and source[a, b] and labels[a, b] == labels[i, j])
        if n >= share * patch * patch - 1e-9:
            centres.append((i, j))
    tg = np.argwhere(targets)
    nnf = np.zeros((len(tg), 2), np.int64)
    cost = np.zeros(len(tg))
    for k, (ti, tj) in enumerate(tg):
        best, arg = np.inf, None
        for si, sj in centres:
            d = patch_distance_reference(work, valid, source, labels, (ti, tj), (si, sj), patch, penalty)
            if d < best:
                best, arg = d, (si, sj)
        nnf[k] = arg
        cost[k] = best
    return NNFResult(nnf, cost, 0)
