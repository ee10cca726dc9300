"""PatchMatch on one pyramid level of a texture (Barnes et al. 2009): padded flat arrays, patch costs,
propagation and random search, voting, and the onion-peel first fill. :mod:`proctex.texture.inpaint`
runs the pyramid and owns the public API."""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import as_strided
from scipy import ndimage


# ------------------------------------------------------------------------------------ one level
class _Level:
    """Padded, flattened arrays of one pyramid level; flat indices address the padded grid.

    ``labels`` are chart ids (0 = gutter): a target texel counts in a patch only if it has the centre's
    chart id, a source texel only if it is source with the source centre's chart id.
    """

    def __init__(self, work, valid, source, labels, patch: int, share: float, penalty: float):
        H, W, C = work.shape
        r = patch // 2
        self.H, self.W, self.C, self.r, self.P = H, W, C, r, patch
        self.Hp, self.Wp = H + 2 * r, W + 2 * r
        self.img = np.zeros((self.Hp * self.Wp, C), np.float32)
        self.img.reshape(self.Hp, self.Wp, C)[r : r + H, r : r + W] = work
        self.valid = self._pad(valid.astype(np.float32))
        self.src = self._pad(source)
        self.lab = self._pad(labels.astype(np.int32))
        self.src_lab = self._pad(np.where(source, labels, 0).astype(np.int32))
        ok = _source_centres(source, labels, patch, share)
        self.n_centres = int(ok.sum())
        self.centre_ok = self._pad(ok)
        self.penalty = np.float32(penalty)
        dy, dx = np.mgrid[-r : r + 1, -r : r + 1]
        self.offs = (dy * self.Wp + dx).ravel().astype(np.int64)
        # Patches are gathered row by row: a strided view whose item k is the P consecutive texels
        # starting at flat index k, so one index per patch row instead of one per texel.
        self.row_offs = (np.arange(-r, r + 1) * self.Wp - r).astype(np.int64)
        n_rows = len(self.img) - patch + 1

        def rows(a):
            return as_strided(a, (n_rows, patch * a[0].size), (a.strides[0], a.strides[-1]))

        self.img_rows = rows(self.img)
        self.valid_rows = rows(self.valid)
        self.lab_rows = rows(self.lab)
        self.src_lab_rows = rows(self.src_lab)
        vote = np.zeros((len(self.img), C + 1), np.float32)  # [colour * is_source, is_source]
        vote[:, :C] = self.img * self.src[:, None]
        vote[:, C] = self.src
        self.vote = vote
        self.vote_rows = rows(vote)
        clean = _clean(labels, patch)
        self.clean = self._pad(clean)  # windows holding one chart (plus gutter)
        # centres whose whole window is source of their own chart: no per-texel source check needed
        self.full = self._pad(source & clean & (_window_count(source, patch) == patch * patch))
        if self.n_centres:
            # nearest valid centre of every in-image texel (for snapping random candidates)
            ii, jj = ndimage.distance_transform_edt(~ok, return_distances=False, return_indices=True)
            self.snap = self.flat(ii.ravel(), jj.ravel())
            self.centres = self.centre_ok.nonzero()[0]

    def _pad(self, a: np.ndarray) -> np.ndarray:
        out = np.zeros((self.Hp, self.Wp), a.dtype)
        out[self.r : self.r + self.H, self.r : self.r + self.W] = a
        return out.ravel()

    def flat(self, rows, cols) -> np.ndarray:
        return (np.asarray(rows, np.int64) + self.r) * self.Wp + (np.asarray(cols, np.int64) + self.r)

    def rc(self, flat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q, m = np.divmod(flat, self.Wp)
        return q - self.r, m - self.r

    def image(self) -> np.ndarray:
        r = self.r
        return self.img.reshape(self.Hp, self.Wp, self.C)[r : r + self.H, r : r + self.W]


def _target_patches(lv: _Level, tgt: np.ndarray):
    """Target patches (N, P*P*C), texel weights (N, P*P), weights per channel (N, P*P*C), sums (N,)."""
    idx = tgt[:, None] + lv.row_offs
    n = len(tgt)
    T = lv.img_rows[idx].reshape(n, -1)
    Wt = lv.valid_rows[idx].reshape(n, -1)
    Wt = Wt * (lv.lab_rows[idx].reshape(n, -1) == lv.lab[tgt][:, None])
    return T, Wt, np.repeat(Wt, lv.C, axis=1), np.maximum(Wt.sum(axis=1), np.float32(1e-12))


def _subset(tp, k: np.ndarray):
    return tuple(a[k] for a in tp)


def _cost(lv: _Level, tp, cand: np.ndarray) -> np.ndarray:
    """Patch distance of targets (their patches ``tp``) to source centres ``cand`` (flat), (N,) float32.

    sum_k Wt_k * (|T_k - S_k|^2 if S_k is source of the centre's chart else penalty) / sum_k Wt_k
    """
    T, Wt, WtC, Wsum = tp
    idx = cand[:, None] + lv.row_offs
    n = len(cand)
    d = T - lv.img_rows[idx].reshape(n, -1)
    np.square(d, out=d)
    num = np.einsum("nj,nj->n", WtC, d)
    part = np.flatnonzero(~lv.full[cand])
    if part.size:
        vs = lv.src_lab_rows[idx[part]].reshape(part.size, -1) == lv.lab[cand[part]][:, None]
        num[part] = np.einsum("nj,nj->n", WtC[part] * np.repeat(vs, lv.C, axis=1), d[part]) + lv.penalty * (Wt[part] * ~vs).sum(axis=1)
    return num / Wsum


def _try(lv, tp, tgt, nnf, cost, nnf_map, cand, m):
    """Evaluate candidates where m is True; keep the strictly better ones (in place)."""
    k = np.flatnonzero(m)
    if k.size == 0:
        return
    if k.size > 0.6 * len(tgt):
        cand = np.where(m, cand, nnf)  # masked-out candidates may lie in the padding
        c = _cost(lv, tp, cand)
        kb = np.flatnonzero(m & (c < cost))
        cb = c[kb]
    else:
        c = _cost(lv, _subset(tp, k), cand[k])
        better = c < cost[k]
        kb = k[better]
        cb = c[better]
    nnf[kb] = cand[kb]
    cost[kb] = cb
    nnf_map[tgt[kb]] = nnf[kb]


def _pm_pass(lv: _Level, tgt, nnf, cost, nnf_map, tp, rng, parity: int, radius: int) -> None:
    """One PatchMatch pass (propagation, then random search) over the targets ``tgt`` (in place)."""
    for delta in (-1, -lv.Wp) if parity % 2 == 0 else (1, lv.Wp):
        nb = nnf_map[tgt + delta]
        cand = np.where(nb >= 0, nb - delta, nnf)
        m = (nb >= 0) & (cand != nnf)
        m[m] = lv.centre_ok[cand[m]]
        _try(lv, tp, tgt, nnf, cost, nnf_map, cand, m)
    rows, cols = lv.rc(nnf)
    n = len(tgt)
    R = int(radius)
    while R >= 1:
        cr = np.clip(rows + rng.integers(-R, R + 1, n), 0, lv.H - 1)
        cc = np.clip(cols + rng.integers(-R, R + 1, n), 0, lv.W - 1)
        cand = lv.snap[cr * lv.W + cc]
        _try(lv, tp, tgt, nnf, cost, nnf_map, cand, cand != nnf)
        R //= 2


def _vote(lv: _Level, tgt: np.ndarray, nnf: np.ndarray, fill_flat: np.ndarray) -> None:
    """Every fill texel := mean of the source colours the overlapping target patches propose.

    A target votes for the texels of its own chart; a source texel counts only if it is source of the
    source centre's chart. Fast path (single-chart target window, all-source source window): the static
    [colour * is_source, is_source] image is added row by row with no masks; votes landing outside
    ``fill`` are accumulated but never read. Other targets take the masked per-offset path.
    """
    C = lv.C
    c1 = C + 1
    acc = np.zeros((len(lv.img), c1), np.float32)
    fast = lv.clean[tgt] & lv.full[nnf]
    tf, nf = tgt[fast], nnf[fast]
    for ro in lv.row_offs:
        rows = lv.vote_rows[nf + ro]  # (n, P * (C + 1))
        base = tf + ro
        for b in range(lv.P):
            acc[base + b] += rows[:, b * c1 : (b + 1) * c1]  # targets distinct -> no duplicate indices
    ts, ns = tgt[~fast], nnf[~fast]
    if ts.size:
        lt, ls = lv.lab[ts], lv.lab[ns]
        for o in lv.offs:
            d, s = ts + o, ns + o
            ok = (lv.src_lab[s] == ls) & (lv.lab[d] == lt)
            acc[d[ok], :C] += lv.img[s[ok]]
            acc[d[ok], C] += 1.0
    f = np.flatnonzero(fill_flat)
    lv.img[f] = acc[f, :C] / acc[f, C:]  # >= 1 vote: each texel's own patch votes its centre


def _random_centres(lv: _Level, n: int, rng) -> np.ndarray:
    return lv.centres[rng.integers(0, len(lv.centres), n)]


def _layer(has: np.ndarray, remaining: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Remaining texels with an 8-neighbour that has colour and the same chart id."""
    H, W = has.shape
    hp, lp = np.pad(has, 1), np.pad(labels, 1)
    out = np.zeros_like(has)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy or dx:
                out |= hp[1 + dy : 1 + dy + H, 1 + dx : 1 + dx + W] & (lp[1 + dy : 1 + dy + H, 1 + dx : 1 + dx + W] == labels)
    return out & remaining


def _onion_fill(lv: _Level, known, fill, labels, nnf_map, rng, passes: int, notes: list[str]) -> int:
    """Initialise the fill texels layer by layer from the hole border inward (centre copy). Returns passes."""
    has = known.copy()
    remaining = fill.copy()
    total = 0
    radius = max(lv.H, lv.W)
    seeded = 0
    while remaining.any():
        layer = _layer(has, remaining, labels)
        if not layer.any():  # components with no coloured texel: one seed each
            lab, n = ndimage.label(remaining, structure=np.ones((3, 3), bool))
            first = ndimage.minimum(np.arange(lab.size).reshape(lab.shape), lab, np.arange(1, n + 1))
            layer = np.zeros_like(remaining)
            layer.ravel()[np.asarray(first, np.int64)] = True
            seeded += n
        ii, jj = np.nonzero(layer)
        tgt = lv.flat(ii, jj)
        nnf = _random_centres(lv, len(tgt), rng)
        tp = _target_patches(lv, tgt)
        cost = _cost(lv, tp, nnf)
        nnf_map[tgt] = nnf
        for p in range(passes):
            _pm_pass(lv, tgt, nnf, cost, nnf_map, tp, rng, p, radius)
        total += passes
        lv.img[tgt] = lv.img[nnf]
        lv.valid[tgt] = 1.0
        has |= layer
        remaining &= ~layer
    if seeded:
        notes.append(f"{seeded} fill component(s) touched no coloured texel of their chart and were seeded from a random source patch")
    return total


def _em(lv: _Level, tgt, nnf, nnf_map, fill_flat, rng, iterations: int, radius: int) -> float:
    """``iterations`` EM steps; returns the mean absolute colour change of the last step."""
    f = np.flatnonzero(fill_flat)
    change = 0.0
    for it in range(iterations):
        before = lv.img[f]
        tp = _target_patches(lv, tgt)
        cost = _cost(lv, tp, nnf)
        _pm_pass(lv, tgt, nnf, cost, nnf_map, tp, rng, it, radius)
        _vote(lv, tgt, nnf, fill_flat)
        change = float(np.abs(lv.img[f] - before).mean())
    return change


def _downsample(work, known, source, fill, labels):
    """Next coarser level. Each 2 x 2 block takes its dominant chart id; it is fill if a texel of that
    chart is fill, else known (mean colour of that chart's known texels) if one is known, and source
    only if all four texels are source of that chart. Gutters therefore never close up."""
    H, W, C = work.shape
    h, w = (H + 1) // 2, (W + 1) // 2

    def blocks(a):
        pad = np.zeros((2 * h, 2 * w) + a.shape[2:], a.dtype)
        pad[:H, :W] = a
        return pad.reshape(h, 2, w, 2, *a.shape[2:]).swapaxes(1, 2).reshape(h, w, 4, *a.shape[2:])

    L4 = blocks(labels)
    votes = (L4[..., :, None] == L4[..., None, :]).sum(-1) * (L4 != 0)
    dom = np.take_along_axis(L4, votes.argmax(-1)[..., None], -1)[..., 0]
    same = (L4 == dom[..., None]) & (dom[..., None] != 0)
    fill_c = (blocks(fill) & same).any(-1)
    kn = blocks(known) & same
    cnt = kn.sum(-1)
    known_c = (cnt > 0) & ~fill_c
    col = (blocks(work) * kn[..., None]).sum(2) / np.maximum(cnt, 1)[..., None]
    source_c = (blocks(source) & same).all(-1)
    labels_c = np.where(fill_c | known_c, dom, 0).astype(np.int32)
    return col.astype(np.float32), known_c, source_c, fill_c, labels_c


def _window_count(mask: np.ndarray, patch: int) -> np.ndarray:
    return ndimage.correlate(mask.astype(np.int32), np.ones((patch, patch), np.int32), mode="constant", cval=0)


def _clean(labels: np.ndarray, patch: int) -> np.ndarray:
    """(H, W) bool: the window holds no label other than 0 (gutter) and the texel's own."""
    hi = ndimage.maximum_filter(labels, size=patch, mode="constant", cval=0)
    big = np.iinfo(np.int32).max
    lo = ndimage.minimum_filter(np.where(labels == 0, big, labels), size=patch, mode="constant", cval=big)
    return (labels > 0) & (hi == labels) & (lo == labels)


def _source_share(source: np.ndarray, labels: np.ndarray, patch: int) -> np.ndarray:
    """(H, W) int32: per texel, the number of window texels in ``source`` with the texel's own label."""
    count = _window_count(source, patch)
    mixed = np.argwhere(source & ~_clean(labels, patch))
    if len(mixed):
        r = patch // 2
        H, W = source.shape
        sl = np.pad(np.where(source, labels, 0), r)  # padded source labels, 0 = not source
        own = labels[mixed[:, 0], mixed[:, 1]]
        n = np.zeros(len(mixed), np.int32)
        for dy in range(patch):
            for dx in range(patch):
                n += sl[mixed[:, 0] + dy, mixed[:, 1] + dx] == own
        count[mixed[:, 0], mixed[:, 1]] = n
    return count


def _source_centres(source: np.ndarray, labels: np.ndarray, patch: int, share: float) -> np.ndarray:
    """(H, W) bool: source texels whose window holds >= share * patch^2 source texels of their chart."""
    return source & (_source_share(source, labels, patch) >= share * patch * patch - 1e-9)
