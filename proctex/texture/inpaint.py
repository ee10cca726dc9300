"""Exemplar PatchMatch fill of unpainted texels (dis-occlusion, docs/texturing.md; issue 5 item 4).

A part group's texture is an atlas of charts. After re-baking or re-texturing, some texels of a chart
were never painted (surface the template never showed). :func:`patchmatch_fill` synthesises them from
patches of the *same* texture, copying only from texels the caller allows (``source``), and never
changes a texel outside ``fill``.

Algorithm (Barnes et al. 2009 for the search, Wexler et al. 2007 for the fill):

- **Charts.** Texels that are neither known nor fill are gutters. Chart ids are the 8-connected
  components of ``known | fill`` (or given by the caller). A patch only "sees" texels of its centre's
  chart: spatial neighbours across a gutter are not surface neighbours, so they must not steer or feed
  the fill (at coarse pyramid levels gutters are thin and would otherwise leak a neighbouring chart in).
- **Patch distance.** A target patch (centred on a fill texel) is compared with a source patch over the
  target texels of the target's chart that hold colour: known texels and fill texels already
  synthesised. Other texels (gutters, other charts, the image border, the not-yet-reached interior of
  the hole) carry weight 0. Where a weighted target texel meets a source-patch texel that is not source
  of the source centre's chart, the pair costs a fixed ``penalty`` (the largest possible squared colour
  difference, ``C * span**2``). The distance is the weighted mean per texel, so costs are comparable
  across patches (:func:`proctex._reference.inpaint.patch_distance_reference` spells it out).
- **Valid source patches** (chart borders). A source centre must itself be in ``source`` and at least
  ``min_source_share`` of its ``patch x patch`` window (texels outside the image count as missing) must
  be source of its chart. The default 0.75 admits patches that straddle a chart border by up to a
  quarter, so thin charts and border texture still have sources, while the penalty above makes fully
  inside patches win whenever they match as well. Voting only reads source texels of the source
  centre's chart, and every texel's own patch votes its (source) centre, so each fill texel always gets
  colour. If no centre qualifies, :func:`patchmatch_fill` raises ``ValueError``.
- **Search.** Nearest-neighbour field (NNF) from target to source centres: random initialisation among
  valid centres, then passes of propagation and random search (radius halving down to 1, from the image
  size at the coarsest level and from ``4 * patch`` at finer levels, which start from the upsampled
  match; random candidates snap to the nearest valid centre so sparse atlases still get useful
  samples). Propagation is vectorised *Jacobi-style*: all targets try their neighbour's shifted match at
  once, left/up neighbours on even passes and right/down on odd passes (the paper's alternating scan
  order), rather than the paper's sequential sweep; a match therefore travels one texel per pass and
  the coarse-to-fine pyramid carries long-range structure. Search without coherence (a noise texture)
  is approximate, as in the paper.
- **Fill order.** At the coarsest level the hole is initialised in onion-peel order: each layer is the set
  of still-empty fill texels with an 8-neighbour of their chart that has colour; its NNF is searched
  with the partial patch distance above and the matched centre colour copied. Fill components that
  touch no colour at all get a seed texel per component (a random valid source) and then grow the same
  way (reported in ``notes``). Afterwards EM steps alternate one PatchMatch pass with *voting*: each
  fill texel becomes the plain mean of the source colours that all overlapping target patches of its
  chart propose for it.
- **Pyramid.** Each 2 x 2 block takes its dominant chart id; it is fill if any texel of that chart in it
  is, known (mean colour) if any is known, source only if all four are source of that chart. Levels
  are added while the short side is at least ``2 * max(16, 4 * patch)`` and the coarse level still has a
  valid source patch. Every level but the finest runs ``iterations`` EM steps; the finest starts from
  the upsampled NNF, votes, and runs ``fine_iterations`` (default ``iterations // 3``), where nearly
  all the time goes and each step changes little (measured: ~4e-4 mean colour change per texel).

Cost: 512 x 512 RGB with a 20 % hole, defaults, ~1.4 s on one core.

Everything random draws from ``numpy.random.default_rng(seed)``: results are deterministic per seed.
:mod:`proctex._reference.inpaint` holds the slow, obviously correct references for
the search and the distance.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from .patchmatch import (
    _cost,
    _downsample,
    _em,
    _Level,
    _onion_fill,
    _pm_pass,
    _random_centres,
    _source_centres,
    _target_patches,
    _vote,
)

DEFAULT_MIN_SOURCE_SHARE = 0.75
FINE_RADIUS_PATCHES = 4  # random-search radius below the coarsest level, in patch widths


# ------------------------------------------------------------------------------------------ results
@dataclass
class PatchMatchResult:
    """Result of :func:`patchmatch_fill`.

    Attributes:
        image: (H, W, C) the filled image, same dtype as the input; texels outside ``fill`` are
            bit-identical to the input.
        nnf: (H, W, 2) int64 (row, col) of the source patch centre matched to each fill texel at the
            finest level; -1 outside ``fill``.
        cost: (H, W) float64 patch distance (mean squared colour difference per weighted texel, colours
            scaled to [0, 1] for uint8) of that match in the final image; NaN outside ``fill``.
        iterations: PatchMatch passes run over all levels (onion layers included).
        seconds: wall time.
        levels: pyramid levels used (1 = no pyramid).
        last_change: mean absolute colour change (working scale: [0, 1] for uint8) of the fill texels
            in the last EM step, a convergence residual; small values mean more steps would change little.
        notes: anything worth telling a user (seeded components, levels dropped).
    """

    image: np.ndarray
    nnf: np.ndarray
    cost: np.ndarray
    iterations: int
    seconds: float
    levels: int = 1
    last_change: float = 0.0
    notes: list[str] = field(default_factory=list)

    @property
    def mean_cost(self) -> float:
        """Mean patch distance over the fill texels (0.0 when nothing was filled)."""
        c = self.cost[np.isfinite(self.cost)]
        return float(c.mean()) if c.size else 0.0


@dataclass
class NNFResult:
    """Result of :func:`patchmatch_nnf` (and of its reference, :mod:`proctex._reference.inpaint`).

    Attributes:
        nnf: (n, 2) int64 (row, col) of the matched source centre per target, targets in row-major order.
        cost: (n,) float64 patch distance of each match.
        iterations: PatchMatch passes run (0 for the brute-force reference).
    """

    nnf: np.ndarray
    cost: np.ndarray
    iterations: int


# ------------------------------------------------------------------------------------- validation
def _as_mask(name: str, m, shape: tuple[int, int]) -> np.ndarray:
    a = np.asarray(m)
    if a.shape != shape:
        raise ValueError(f"{name} must be an (H, W) = {shape} mask, got shape {a.shape}")
    if a.dtype != bool:
        if not (np.issubdtype(a.dtype, np.integer) or np.issubdtype(a.dtype, np.floating)):
            raise ValueError(f"{name} must be boolean, got dtype {a.dtype}")
        if not np.isin(a, (0, 1)).all():
            raise ValueError(f"{name} must be boolean (only 0/1 values), got other values")
        a = a.astype(bool)
    return a


def _check_image(image) -> tuple[np.ndarray, np.ndarray]:
    """Returns (original array, float32 working copy in [0, 1] for uint8 input)."""
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[0] < 1 or img.shape[1] < 1 or img.shape[2] < 1:
        raise ValueError(f"image must be (H, W, C) with H, W, C >= 1, got shape {img.shape}")
    if img.dtype == np.uint8:
        work = img.astype(np.float32) / np.float32(255.0)
    elif np.issubdtype(img.dtype, np.floating):
        if not np.isfinite(img).all():
            raise ValueError("image contains NaN or inf")
        work = img.astype(np.float32)
    else:
        raise ValueError(f"image must be uint8 or floating point, got dtype {img.dtype}")
    return img, work


def _check_patch(patch) -> int:
    if isinstance(patch, bool) or not isinstance(patch, (int, np.integer)) or patch < 3 or patch % 2 == 0:
        raise ValueError(f"patch must be an odd integer >= 3, got {patch!r}")
    return int(patch)


def _check_share(share) -> float:
    s = float(share)
    if not (0.0 < s <= 1.0):
        raise ValueError(f"min_source_share must be in (0, 1], got {share!r}")
    return s


def _penalty(work: np.ndarray, source: np.ndarray) -> float:
    vals = work[source]
    span = float(vals.max() - vals.min()) if vals.size else 0.0
    return float(work.shape[2]) * (span if span > 0 else 1.0) ** 2


def chart_labels(mask: np.ndarray) -> np.ndarray:
    """(H, W) int32 chart ids of a texture: 8-connected components of ``mask`` (its painted or
    covered texels) numbered from 1, 0 outside it. The one definition: the run-time coverage check
    (:mod:`proctex.transfer.apply`) uses it too."""
    lab, _ = ndimage.label(np.asarray(mask, dtype=bool), structure=np.ones((3, 3), dtype=bool))
    return lab.astype(np.int32)


# ------------------------------------------------------------------------------------ public API
def patchmatch_fill(
    image: np.ndarray,
    known: np.ndarray,
    fill: np.ndarray,
    patch: int = 7,
    iterations: int = 6,
    seed: int = 0,
    source: np.ndarray | None = None,
    pyramid: bool = True,
    min_source_share: float = DEFAULT_MIN_SOURCE_SHARE,
    charts: np.ndarray | None = None,
    fine_iterations: int | None = None,
) -> PatchMatchResult:
    """Synthesise the ``fill`` texels of ``image`` from patches of its ``source`` texels.

    Args:
        image: (H, W, C) uint8 or float texture (float: finite, normally in [0, 1]).
        known: (H, W) bool texels holding valid colour (they steer the match; they are never changed).
            Pass the painted texels, not a seam-padded mask: gutter texels must be in neither mask.
        fill: (H, W) bool texels to synthesise; disjoint from ``known``. Texels in neither mask (gutters)
            are ignored and left unchanged.
        patch: odd patch width >= 3.
        iterations: EM steps (one PatchMatch pass + voting each) per pyramid level, >= 1.
        fine_iterations: EM steps at the finest level of a pyramid (it starts from the upsampled
            match, and it is where all the time goes); default ``max(1, iterations // 3)``. A single
            level (``pyramid=False`` or a small image) always runs ``iterations``.
        seed: seed of the random generator (results are deterministic per seed).
        source: (H, W) bool subset of ``known`` that may be copied from; default ``known``.
        pyramid: coarse-to-fine (recommended for large holes); False runs a single level.
        min_source_share: share of a source patch's window that must be ``source`` (module docstring).
        charts: optional (H, W) int chart ids (> 0 on known and fill texels); default: the 8-connected
            components of ``known | fill``. Patch texels of another chart than the patch centre's are
            ignored (target side) or penalised (source side), so context never leaks across gutters.

    Returns:
        :class:`PatchMatchResult`. Texels outside ``fill`` are bit-identical to ``image``.

    Raises:
        ValueError: bad shapes/dtypes/values, overlapping masks, ``source`` not within ``known``, or a
            non-empty ``fill`` with no valid source patch.
    """
    t0 = time.perf_counter()
    orig, work = _check_image(image)
    H, W, C = orig.shape
    known = _as_mask("known", known, (H, W))
    fill = _as_mask("fill", fill, (H, W))
    source = known if source is None else _as_mask("source", source, (H, W))
    patch = _check_patch(patch)
    share = _check_share(min_source_share)
    iterations = _check_iterations(iterations)
    fine_iterations = max(1, iterations // 3) if fine_iterations is None else _check_iterations(fine_iterations)
    if (known & fill).any():
        raise ValueError(f"known and fill overlap in {int((known & fill).sum())} texels; they must be disjoint")
    if (source & ~known).any():
        raise ValueError(f"source must be a subset of known; {int((source & ~known).sum())} source texels are not known")
    labels = _check_labels(charts, known | fill)
    nnf_out = np.full((H, W, 2), -1, np.int64)
    cost_out = np.full((H, W), np.nan)
    if not fill.any():
        return PatchMatchResult(orig.copy(), nnf_out, cost_out, 0, time.perf_counter() - t0, 1, 0.0)
    if not source.any():
        raise ValueError("source is empty: no texel to copy from")
    if not _source_centres(source, labels, patch, share).any():
        raise ValueError(
            f"no valid source patch: no source texel has {share:.0%} of its {patch}x{patch} window in source of its chart ({int(source.sum())} source texels); use a smaller patch or min_source_share"
        )
    rng = np.random.default_rng(seed)
    penalty = _penalty(work, source)
    notes: list[str] = []

    # pyramid: list of (work, known, source, fill, labels), finest first
    pyr = [(work, known, source, fill, labels)]
    min_size = max(16, 4 * patch)
    while pyramid and min(pyr[-1][0].shape[:2]) >= 2 * min_size:
        c = _downsample(*pyr[-1])
        if not _source_centres(c[2], c[4], patch, share).any():
            notes.append(f"pyramid stopped at {len(pyr)} level(s): the next coarser level has no valid source patch")
            break
        pyr.append(c)

    passes = 0
    prev = None  # (level, nnf_map) of the coarser level
    for li in range(len(pyr) - 1, -1, -1):
        w_l, k_l, s_l, f_l, l_l = pyr[li]
        lv = _Level(w_l, k_l, s_l, l_l, patch, share, penalty)
        nnf_map = np.full(lv.Hp * lv.Wp, -1, np.int64)
        ii, jj = np.nonzero(f_l)
        tgt = lv.flat(ii, jj)
        fill_flat = lv._pad(f_l)
        if prev is None:
            passes += _onion_fill(lv, k_l, f_l, l_l, nnf_map, rng, max(2, iterations // 2), notes)
            nnf = nnf_map[tgt].copy()
        else:
            plv, pmap = prev
            parent = pmap[plv.flat(ii // 2, jj // 2)]
            cr, cc = plv.rc(np.maximum(parent, 0))
            fr = np.clip(2 * cr + (ii % 2), 0, lv.H - 1)
            fc = np.clip(2 * cc + (jj % 2), 0, lv.W - 1)
            nnf = lv.snap[fr * lv.W + fc]
            orphan = parent < 0  # the coarse block belonged to another chart
            nnf[orphan] = _random_centres(lv, int(orphan.sum()), rng)
            nnf_map[tgt] = nnf
            _vote(lv, tgt, nnf, fill_flat)
            lv.valid[tgt] = 1.0
        radius = max(lv.H, lv.W) if prev is None else min(max(lv.H, lv.W), FINE_RADIUS_PATCHES * patch)
        steps = fine_iterations if (li == 0 and len(pyr) > 1) else iterations
        last_change = _em(lv, tgt, nnf, nnf_map, fill_flat, rng, steps, radius)
        passes += steps
        prev = (lv, nnf_map)

    # final cost against the final image, and write back only the fill texels
    final_cost = _cost(lv, _target_patches(lv, tgt), nnf)
    sr, sc = lv.rc(nnf)
    nnf_out[ii, jj, 0] = sr
    nnf_out[ii, jj, 1] = sc
    cost_out[ii, jj] = final_cost
    out = orig.copy()
    vals = lv.image()[ii, jj]
    if orig.dtype == np.uint8:
        out[ii, jj] = np.clip(np.rint(vals * 255.0), 0, 255).astype(np.uint8)
    else:
        out[ii, jj] = vals.astype(orig.dtype)
    return PatchMatchResult(out, nnf_out, cost_out, passes, time.perf_counter() - t0, len(pyr), last_change, notes)


def _check_iterations(iterations) -> int:
    if isinstance(iterations, bool) or not isinstance(iterations, (int, np.integer)) or iterations < 1:
        raise ValueError(f"iterations must be an integer >= 1, got {iterations!r}")
    return int(iterations)


def _check_labels(charts, covered: np.ndarray) -> np.ndarray:
    if charts is None:
        return chart_labels(covered)
    lab = np.asarray(charts)
    if lab.shape != covered.shape:
        raise ValueError(f"charts must be an (H, W) = {covered.shape} int array, got shape {lab.shape}")
    if not np.issubdtype(lab.dtype, np.integer):
        raise ValueError(f"charts must hold integer chart ids, got dtype {lab.dtype}")
    if lab.min(initial=0) < 0 or lab.max(initial=0) > np.iinfo(np.int32).max - 1:
        raise ValueError("chart ids must be in [0, 2**31 - 2]")
    if (lab[covered] <= 0).any():
        raise ValueError("charts must be > 0 on every known, fill, valid or target texel")
    return np.where(covered, lab, 0).astype(np.int32)


def _prepare_nnf_inputs(image, valid, source, targets, patch, share, charts):
    _, work = _check_image(image)
    H, W, _ = work.shape
    valid = _as_mask("valid", valid, (H, W))
    source = _as_mask("source", source, (H, W))
    targets = _as_mask("targets", targets, (H, W))
    patch = _check_patch(patch)
    share = _check_share(share)
    if (source & ~valid).any():
        raise ValueError("source must be a subset of valid")
    labels = _check_labels(charts, valid | targets)
    if not _source_centres(source, labels, patch, share).any():
        raise ValueError("no valid source patch centre")
    return work, valid, source, targets, patch, share, labels


def patchmatch_nnf(
    image: np.ndarray,
    valid: np.ndarray,
    source: np.ndarray,
    targets: np.ndarray,
    patch: int = 7,
    iterations: int = 5,
    seed: int = 0,
    min_source_share: float = DEFAULT_MIN_SOURCE_SHARE,
    charts: np.ndarray | None = None,
) -> NNFResult:
    """PatchMatch search alone, on a fixed image (no fill): the best source centre for each target.

    Args:
        image: (H, W, C); valid: (H, W) bool texels whose colour counts in the distance (target side);
        source: (H, W) bool subset of ``valid`` that may be copied from; targets: (H, W) bool patch
        centres to match (any texels); patch, min_source_share: as in :func:`patchmatch_fill`;
        iterations: PatchMatch passes; charts: chart ids (default: components of ``valid | targets``).
    """
    work, valid, source, targets, patch, share, labels = _prepare_nnf_inputs(image, valid, source, targets, patch, min_source_share, charts)
    iterations = _check_iterations(iterations)
    rng = np.random.default_rng(seed)
    lv = _Level(work, valid, source, labels, patch, share, _penalty(work, source))
    ii, jj = np.nonzero(targets)
    tgt = lv.flat(ii, jj)
    nnf = _random_centres(lv, len(tgt), rng)
    nnf_map = np.full(lv.Hp * lv.Wp, -1, np.int64)
    nnf_map[tgt] = nnf
    tp = _target_patches(lv, tgt)
    cost = _cost(lv, tp, nnf)
    for p in range(iterations):
        _pm_pass(lv, tgt, nnf, cost, nnf_map, tp, rng, p, max(lv.H, lv.W))
    sr, sc = lv.rc(nnf)
    return NNFResult(np.stack([sr, sc], axis=1), cost.astype(np.float64), iterations)


# ------------------------------------------------------------------------------------ references
