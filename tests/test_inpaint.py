"""Exemplar PatchMatch fill (proctex.texture.inpaint): quality, search optimality, guarantees, validation."""

import numpy as np
import pytest

import proctex.texture.inpaint as ip
import proctex.texture.patchmatch as pm
from proctex._reference.inpaint import nnf_reference, patch_distance_reference
from proctex.texture.inpaint import chart_labels, patchmatch_fill, patchmatch_nnf


def _checker(H, W, period=8, noise=0.0, seed=0):
    ii, jj = np.mgrid[0:H, 0:W]
    a = ((ii // (period // 2) + jj // (period // 2)) % 2).astype(np.float32)
    img = np.stack([0.2 + 0.6 * a, 0.7 - 0.4 * a, 0.5 + 0.3 * np.sin(2 * np.pi * jj / period)], axis=-1)
    if noise:
        img = img + np.random.default_rng(seed).normal(0, noise, img.shape)
    return np.clip(img, 0, 1).astype(np.float32)


def _stripes(H, W, period=6):
    ii, _ = np.mgrid[0:H, 0:W]
    a = (ii % period < period // 2).astype(np.float32)
    return np.stack([0.9 * a + 0.05, 0.3 * a + 0.1, 0.1 + 0 * a], axis=-1).astype(np.float32)


# ---------------------------------------------------------------------------------------- quality
@pytest.mark.parametrize("pyramid", [True, False])
def test_periodic_texture_is_resynthesised(pyramid):
    img = _checker(96, 96)
    fill = np.zeros((96, 96), bool)
    fill[30:62, 34:70] = True
    res = patchmatch_fill(img, ~fill, fill, pyramid=pyramid, seed=1)
    err = np.abs(res.image - img)[fill].mean()
    mean_fill = np.abs(img[~fill].mean(axis=0) - img)[fill].mean()
    assert err < 0.05, err
    assert err < 0.2 * mean_fill
    assert res.levels == (2 if pyramid else 1)
    assert np.isfinite(res.image).all() and res.mean_cost < 1e-3


def test_fill_copies_the_region_it_lies_in():
    """Region A (horizontal stripes, warm) left, region B (checker, cool) right; the hole is inside A."""
    H, W = 64, 96
    img = np.concatenate([_stripes(H, 48), _checker(H, 48)[..., ::-1]], axis=1)
    fill = np.zeros((H, W), bool)
    fill[20:44, 12:34] = True  # >= 14 texels from B
    res = patchmatch_fill(img, ~fill, fill, seed=3)
    src_cols = res.nnf[fill][:, 1]
    assert (src_cols < 48).mean() > 0.95  # matched patches come from A
    err = np.abs(res.image - img)[fill].mean()
    assert err < 0.05, err
    # the fill has A's colours (warm: red >= blue), not B's
    out = res.image[fill]
    assert (out[:, 0] >= out[:, 2] - 0.05).mean() > 0.95


def test_fill_does_not_leak_across_a_chart_gutter():
    """A hole touching a gutter must not take its context from the chart across the gutter, at any level."""
    H, W = 128, 128
    img = np.zeros((H, W, 3), np.float32)
    img[:, :60] = _stripes(H, 60)
    img[:, 68:] = [0.1, 0.2, 0.9]  # chart B: flat blue
    known = np.ones((H, W), bool)
    known[:, 60:68] = False  # gutter, neither known nor fill
    fill = np.zeros((H, W), bool)
    fill[40:90, 30:60] = True  # chart A, against the gutter
    known &= ~fill
    res = patchmatch_fill(img, known, fill, seed=0)
    assert res.levels >= 2
    out = res.image[fill]
    assert (out[:, 2] < 0.5).all()  # no blue from chart B
    assert np.abs(res.image - img)[fill].mean() < 0.05
    gutter = ~known & ~fill
    np.testing.assert_array_equal(res.image[gutter], img[gutter])


def test_explicit_charts_separate_touching_charts():
    """Two charts that touch (no gutter) are one component by default; explicit ids keep them apart."""
    H, W = 64, 64
    img = np.zeros((H, W, 3), np.float32)
    img[:, :32] = _stripes(H, 32)
    img[:, 32:] = [0.1, 0.2, 0.9]
    charts = np.where(np.arange(W)[None, :] < 32, 1, 2) * np.ones((H, 1), int)
    fill = np.zeros((H, W), bool)
    fill[20:44, 16:32] = True  # chart 1, against chart 2
    res = patchmatch_fill(img, ~fill, fill, charts=charts, seed=0)
    assert (res.image[fill][:, 2] < 0.5).all()
    assert np.abs(res.image - img)[fill].mean() < 0.05


def test_source_restricts_where_colours_come_from():
    img = np.concatenate([_stripes(48, 32), _stripes(48, 32)[..., ::-1]], axis=1)
    fill = np.zeros((48, 64), bool)
    fill[16:32, 40:56] = True
    known = ~fill
    source = known.copy()
    source[:, 32:] = False  # may only copy from the left half
    res = patchmatch_fill(img, known, fill, source=source, seed=0)
    assert (res.nnf[fill][:, 1] < 32).all()
    ii, jj = res.nnf[fill].T
    assert source[ii, jj].all()


# ---------------------------------------------------------------------------------- NNF search
def _nnf_case():
    rng = np.random.default_rng(5)
    H = W = 16
    img = _checker(H, W, period=6, noise=0.05, seed=2)
    img = np.clip(img + 0.1 * rng.random((H, W, 1)), 0, 1).astype(np.float32)
    valid = np.ones((H, W), bool)
    valid[:, 7] = False  # a gutter column: two charts
    valid[5:9, 9:13] = False  # a hole
    targets = np.zeros((H, W), bool)
    targets[4:10, 8:14] = True  # hole and its ring (partial target patches)
    targets[12:16, 0:4] = True  # at the image corner
    targets &= ~(np.arange(W)[None, :] == 7)
    source = valid & ~targets
    source[0:3, 0:6] = False
    return img, valid, source, targets


def test_patch_distance_matches_reference():
    img, valid, source, targets = _nnf_case()
    labels = chart_labels(valid | targets)
    res = patchmatch_nnf(img, valid, source, targets, patch=3, iterations=2, seed=0, min_source_share=0.5)
    pen = ip._penalty(img.astype(np.float32), source)
    ref = [patch_distance_reference(img, valid, source, labels, tuple(t), tuple(s), 3, pen) for t, s in zip(np.argwhere(targets), res.nnf)]
    np.testing.assert_allclose(res.cost, ref, rtol=1e-5, atol=1e-6)


def test_valid_centres_match_explicit_count():
    img, valid, source, targets = _nnf_case()
    labels = chart_labels(valid | targets)
    for patch, share in ((3, 0.5), (3, 1.0), (5, 0.75)):
        fast = pm._source_centres(source, labels, patch, share)
        r = patch // 2
        slow = np.zeros_like(fast)
        for i, j in np.argwhere(source):
            n = sum(source[a, b] and labels[a, b] == labels[i, j] for a in range(max(0, i - r), min(16, i + r + 1)) for b in range(max(0, j - r), min(16, j + r + 1)))
            slow[i, j] = n >= share * patch * patch
        np.testing.assert_array_equal(fast, slow)


def test_patchmatch_nnf_reaches_the_brute_force_optimum():
    """A target block that is a (noisy) copy of another block: the optimal NNF is coherent, and
    PatchMatch (random search + propagation) must find it, as the brute-force reference does."""
    from scipy import ndimage

    rng = np.random.default_rng(4)
    H = W = 16
    f = ndimage.gaussian_filter(rng.random((H, W, 3)), (1.2, 1.2, 0))
    img = (f - f.min()) / (f.max() - f.min())
    img[8:15, 8:15] = img[1:8, 2:9] + rng.normal(0, 0.01, (7, 7, 3))
    img = np.clip(img, 0, 1).astype(np.float32)
    valid = np.ones((H, W), bool)
    targets = np.zeros((H, W), bool)
    targets[9:14, 9:14] = True
    source = valid & ~targets
    ref = nnf_reference(img, valid, source, targets, patch=3)
    np.testing.assert_array_equal(ref.nnf, np.argwhere(targets) - [7, 6])  # the copy is the optimum
    for seed in range(3):
        pm = patchmatch_nnf(img, valid, source, targets, patch=3, iterations=10, seed=seed)
        assert pm.cost.sum() <= 1.03 * ref.cost.sum()
        assert (pm.cost >= ref.cost - 1e-6).all()  # nothing beats brute force


def test_patchmatch_nnf_on_an_incoherent_field_improves_and_never_beats_brute_force():
    img, valid, source, targets = _nnf_case()
    ref = nnf_reference(img, valid, source, targets, patch=3, min_source_share=0.5)
    costs = [patchmatch_nnf(img, valid, source, targets, patch=3, iterations=it, seed=0, min_source_share=0.5).cost for it in (1, 4, 16)]
    for c in costs:
        assert (c >= ref.cost - 1e-6).all()
    assert costs[0].sum() >= costs[1].sum() >= costs[2].sum()
    assert costs[2].sum() <= 2.0 * ref.cost.sum()  # approximate without coherence (measured 1.3-1.6x)


def test_vote_matches_per_texel_reference():
    """The fast masked/unmasked vote equals a per-texel mean over overlapping target patches."""
    rng = np.random.default_rng(1)
    H, W, P = 20, 20, 5
    img = rng.random((H, W, 3)).astype(np.float32)
    known = np.ones((H, W), bool)
    known[:, 10] = False  # gutter: two charts, partial windows
    fill = np.zeros((H, W), bool)
    fill[6:14, 4:10] = True
    fill[3:6, 13:17] = True
    known &= ~fill
    labels = chart_labels(known | fill)
    lv = pm._Level(img, known, known, labels, P, 0.5, 3.0)
    ii, jj = np.nonzero(fill)
    tgt = lv.flat(ii, jj)
    nnf = pm._random_centres(lv, len(tgt), rng)
    before = lv.image().copy()
    pm._vote(lv, tgt, nnf, lv._pad(fill))
    got = lv.image()
    sr, sc = lv.rc(nnf)
    r = P // 2
    for y, x in zip(ii, jj):
        votes = []
        for k, (ty, tx) in enumerate(zip(ii, jj)):
            dy, dx = y - ty, x - tx
            if max(abs(dy), abs(dx)) > r or labels[ty, tx] != labels[y, x]:
                continue
            a, b = sr[k] + dy, sc[k] + dx
            if 0 <= a < H and 0 <= b < W and known[a, b] and labels[a, b] == labels[sr[k], sc[k]]:
                votes.append(before[a, b])
        np.testing.assert_allclose(got[y, x], np.mean(votes, axis=0), atol=1e-5)


# ---------------------------------------------------------------------------------- guarantees
def test_never_repaints_known_texels_and_is_deterministic():
    rng = np.random.default_rng(0)
    img = _checker(64, 64, noise=0.03)
    known = rng.random((64, 64)) > 0.05  # scattered unknown texels
    fill = np.zeros((64, 64), bool)
    fill[10:30, 20:50] = True
    gutter = np.zeros((64, 64), bool)
    gutter[40:44] = True
    known &= ~fill & ~gutter
    fill &= ~gutter
    untouched = ~fill
    a = patchmatch_fill(img, known, fill, seed=7)
    b = patchmatch_fill(img, known, fill, seed=7)
    c = patchmatch_fill(img, known, fill, seed=8)
    assert a.image[untouched].tobytes() == img[untouched].tobytes()  # bit-identical
    np.testing.assert_array_equal(a.image, b.image)
    np.testing.assert_array_equal(a.nnf, b.nnf)
    assert not np.array_equal(a.nnf, c.nnf)
    assert np.isfinite(a.image).all() and a.image.dtype == img.dtype
    assert (a.nnf[fill] >= 0).all() and (a.nnf[~fill] == -1).all()
    assert np.isfinite(a.cost[fill]).all() and np.isnan(a.cost[~fill]).all()
    ii, jj = a.nnf[fill].T
    assert known[ii, jj].all()
    # float64 and uint8 images
    i8 = (img * 255).astype(np.uint8)
    r8 = patchmatch_fill(i8, known, fill, seed=7)
    assert r8.image.dtype == np.uint8
    np.testing.assert_array_equal(r8.image[untouched], i8[untouched])
    assert np.abs(r8.image[fill].astype(float) / 255 - a.image[fill]).mean() < 0.05
    r64 = patchmatch_fill(img.astype(np.float64), known, fill, seed=7)
    assert r64.image.dtype == np.float64
    np.testing.assert_array_equal(r64.image[untouched], img.astype(np.float64)[untouched])


def test_every_fill_texel_gets_colour_even_in_a_chart_without_known_texels():
    img = _checker(48, 48)
    known = np.zeros((48, 48), bool)
    known[:, :20] = True
    fill = np.zeros((48, 48), bool)
    fill[10:30, 28:44] = True  # a chart of its own, separated by a gutter, nothing known in it
    orig = img.copy()
    img[fill] = 0.0
    res = patchmatch_fill(img, known, fill, seed=0)
    assert any("seeded" in n for n in res.notes)
    assert np.isfinite(res.image).all()
    assert (res.nnf[fill] >= 0).all()
    lo, hi = orig[known].min(axis=0), orig[known].max(axis=0)
    assert ((res.image[fill] >= lo - 1e-6) & (res.image[fill] <= hi + 1e-6)).all()


def test_empty_fill_returns_a_copy():
    img = _checker(16, 16)
    res = patchmatch_fill(img, np.ones((16, 16), bool), np.zeros((16, 16), bool))
    np.testing.assert_array_equal(res.image, img)
    assert res.image is not img and res.iterations == 0 and (res.nnf == -1).all()


def test_large_texture_smoke():
    """A 256^2 texture with a 20 % hole is filled well (its time is a benchmark figure, not asserted)."""
    H = W = 256  # a quarter of the work, to keep the suite quick
    img = _checker(H, W, period=16, noise=0.02)
    yy, xx = np.mgrid[0:H, 0:W]
    fill = (yy - H / 2) ** 2 + (xx - W / 2) ** 2 < 0.2 * H * W / np.pi
    res = patchmatch_fill(img, ~fill, fill, seed=0)
    assert np.abs(res.image - img)[fill].mean() < 0.05


# ---------------------------------------------------------------------------------- validation
@pytest.mark.parametrize(
    "change",
    [
        dict(image=np.zeros((16, 16))),
        dict(image=np.zeros((16, 16, 3), np.int32)),
        dict(image=np.full((16, 16, 3), np.nan)),
        dict(known=np.ones((16, 15), bool)),
        dict(fill=np.ones((15, 16), bool)),
        dict(known=np.ones((16, 16), bool)),  # overlaps fill
        dict(known=np.full((16, 16), 0.5)),
        dict(source=np.zeros((16, 16), bool)),  # empty source
        dict(source=np.ones((16, 16), bool)),  # not within known
        dict(patch=4),
        dict(patch=1),
        dict(patch=3.0),
        dict(iterations=0),
        dict(min_source_share=0.0),
        dict(min_source_share=1.5),
        dict(charts=np.zeros((16, 16), int)),
        dict(charts=np.ones((16, 16), float)),
    ],
)
def test_bad_input_raises(change):
    fill = np.zeros((16, 16), bool)
    fill[4:8, 4:8] = True
    args = dict(image=_checker(16, 16), known=~fill, fill=fill)
    args.update(change)
    with pytest.raises(ValueError):
        patchmatch_fill(**args)


def test_no_valid_source_patch_raises():
    img = _checker(24, 24)
    known = np.zeros((24, 24), bool)
    known[10, :] = True  # a one-texel line: no 7x7 window is 75 % source
    fill = np.zeros((24, 24), bool)
    fill[12:16, 5:10] = True
    with pytest.raises(ValueError, match="no valid source patch"):
        patchmatch_fill(img, known, fill)
    res = patchmatch_fill(img, known, fill, patch=3, min_source_share=1 / 3)  # a thin source works with a small share
    assert (res.nnf[fill][:, 0] == 10).all()
