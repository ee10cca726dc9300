"""Looks from photos: a photo (an *exemplar*) per part group, synthesised on the surface (issue 53).

Reading (:mod:`proctex.texture.photo`, :func:`read_photo`): a photo's bytes become an sRGB
``(H, W, 3)`` float32 image, its size checked from the header before any pixel is decoded.

Preparing (:func:`prepare`): the photo at the size one texel's footprint asks for (a minified photo
is resampled first, so the synthesis never aliases), and seven channels made from it: the colour in
its principal axes (decorrelated, as Heitz and Neyret 2018 do) and a local contrast (for roughness),
each *Gaussianised* (every value replaced by the normal quantile of its rank; a table of the
channel's quantiles takes a Gaussian value back), and a height (the high-passed luminance at unit
variance) with its two derivatives (for the relief), kept as they are.

Synthesis (:func:`synthesise`): histogram-preserving tiling and blending (Heitz and Neyret 2018, "High-
Performance By-Example Noise using a Histogram-Preserving Blending Operator"). The plane is covered
by a triangle grid; each grid vertex takes a random patch of the Gaussianised photo (its offset a hash
of the vertex and the seed), and a point blends the three patches of its triangle with its barycentric
weights, divided by the root of their squares (so the blend keeps the Gaussian's variance: no washed-
out mixtures), before the quantile table restores the photo's own histogram. The patches never cross
the photo's border (the offsets keep a margin of the triangle's size), so no edge of the photo is
ever shown, and each vertex draws its own offset: nothing repeats on a grid.

On a part (:class:`PhotoPainter`): points are expressed in the group's principal frame (its
representative part's axes, longest first: a photo's horizontal axis runs along the part's long axis
unless rotated) at the photo's physical scale, and the three axis-aligned projections are blended by
a smooth normal field's components (tri-planar) with the same variance-keeping blend. Colour is a
function of the 3D point and that field, both continuous across UV charts: the texture has no seams
of its own (and :func:`proctex.texture.paint.paint_surface` paints a ring of texels past each chart's
edge, so chart borders read true colours too).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .photo import (  # noqa: F401  (reading is photo.py's; these names are read from here too)
    Photo,
    read_photo,
    parse_length,
    MAX_PHOTO_PIXELS,
    MAX_PHOTO_BYTES,
    MIN_PHOTO_SIDE,
    FORMATS,
    WORK_SIDE,
    UNITS,
    _resize,
)

__all__ = ["Photo", "PhotoLayer", "Exemplar", "PhotoPainter", "read_photo", "prepare", "synthesise", "tiled", "parse_length", "MAX_PHOTO_PIXELS", "MAX_PHOTO_BYTES", "FORMATS", "UNITS"]

#: the grid's edge (photo pixels per grid unit) as a share of the photo's shorter side: each vertex's
#: patch spans about 0.6 of the photo, and every patch lies inside it.
CELL = 0.25
#: how far a point may lie from a vertex of its triangle (grid units: the triangles' edge).
REACH = 1.0
#: the tri-planar blend's sharpness (weights |n_k|^SHARP).
SHARP = 4.0
#: points per evaluation chunk (bounds the temporaries).
CHUNK = 65536
#: the most bytes of contrast and relief a painter keeps from :meth:`PhotoPainter.paint` for
#: :meth:`PhotoPainter.material` (16 per texel: every group of a 1024² look; larger looks recompute).
KEEP_BYTES = 128 * 2**20
#: the quantile table's length per channel.
LUT = 1024


@dataclass(frozen=True)
class Exemplar:
    """A photo ready to synthesise from (:func:`prepare`).

    Attributes:
        gauss: ``(h, w, 7)`` float32 channels: the Gaussianised colour along its 3 principal axes
            and local contrast (:data:`COLOUR`, :data:`CONTRAST`), then the height (high-passed
            luminance at unit variance) and its two derivatives per photo pixel along the columns and
            rows (:data:`RELIEF`), kept as they are (blending keeps their variance).
        lut: ``(4, LUT)`` float32, the Gaussianised channels' quantiles (at the normal CDF of evenly
            spaced Gaussian values :data:`_GRID`): a Gaussian value back to the channel's own.
        mean: ``(3,)`` and ``axes`` ``(3, 3)``: the colour's mean and principal axes (rows).
        contrast: the median local contrast (roughness is read relative to it).
        pixel: the physical size of one of its pixels, in the family's units.
    """

    gauss: np.ndarray
    lut: np.ndarray
    mean: np.ndarray
    axes: np.ndarray
    contrast: float
    pixel: float

    _quads: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def shape(self) -> tuple[int, int]:
        return self.gauss.shape[0], self.gauss.shape[1]

    def quads(self, channels: list[int]) -> np.ndarray:
        """:func:`quads` of ``channels`` (made once per channel set)."""
        key = tuple(channels)
        if key not in self._quads:
            self._quads[key] = quads(self.gauss[..., list(channels)])
        return self._quads[key]


_GRID = np.linspace(-4.0, 4.0, LUT)
#: the channels of :attr:`Exemplar.gauss`: colour (Gaussianised), contrast (Gaussianised), relief
#: (height, d/dx, d/dy as they are).
COLOUR, CONTRAST, RELIEF = [0, 1, 2], [3], [4, 5, 6]


def _ndtr(x: np.ndarray) -> np.ndarray:
    from scipy.special import ndtr

    return ndtr(x)


def prepare(photo: Photo | np.ndarray, pixel: float, texel: float | None = None) -> Exemplar:
    """Get a photo ready to synthesise from.

    Args:
        photo: a :class:`Photo` (or its ``(H, W, 3)`` float RGB in [0, 1]).
        pixel: the physical size of one photo pixel (the photo's scale / its width), family units.
        texel: the physical size of one texel where it is painted; a photo finer than that is
            resampled first to one pixel per texel (at least 32 pixels a side), so its detail is
            averaged as a texel would average it instead of aliasing.
    Returns:
        :class:`Exemplar`.
    """
    from scipy.ndimage import gaussian_filter
    from scipy.special import ndtri

    rgb = np.asarray(photo.rgb if isinstance(photo, Photo) else photo, dtype=np.float32)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or min(rgb.shape[:2]) < 2:
        raise ValueError(f"a photo is (H, W, 3), got {rgb.shape}")
    if not (np.isfinite(pixel) and pixel > 0):
        raise ValueError(f"pixel size must be positive, got {pixel!r}")
    H, W = rgb.shape[:2]
    if texel is not None and np.isfinite(texel) and texel > pixel * 1.25:
        k = max(pixel / texel, 32.0 / min(H, W))
        if k < 1.0:
            rgb = _resize(rgb, max(2, round(W * k)), max(2, round(H * k)))
            pixel = pixel * W / rgb.shape[1]
            H, W = rgb.shape[:2]
    flat = rgb.reshape(-1, 3).astype(np.float64)
    mean = flat.mean(axis=0)
    cov = np.cov((flat - mean).T) + np.eye(3) * 1e-9
    _, vecs = np.linalg.eigh(cov)
    axes = vecs[:, ::-1].T  # rows: principal axes, largest first
    colour = (flat - mean) @ axes.T
    lum = rgb @ np.array([0.2126, 0.7152, 0.0722], np.float32)
    height = lum - gaussian_filter(lum, max(H, W) / 32.0, mode="reflect")
    height = height / max(float(height.std()), 1e-6)  # unit variance: the relief's strength is the layer's
    hy, hx = np.gradient(height)  # per photo pixel
    m1 = gaussian_filter(lum, 2.0, mode="reflect")
    contrast = np.sqrt(np.maximum(gaussian_filter(lum * lum, 2.0, mode="reflect") - m1 * m1, 0.0))
    chans = np.concatenate([colour, contrast.reshape(-1, 1)], axis=1)
    n = len(chans)
    gauss = np.empty((n, 7), dtype=np.float32)
    lut = np.empty((4, LUT), np.float32)
    qs = _ndtr(_GRID)
    ranks = ndtri((np.arange(n) + 0.5) / n)
    for c in range(4):
        order = np.argsort(chans[:, c], kind="stable")
        gauss[order, c] = ranks
        lut[c] = np.interp(qs * (n - 1), np.arange(n), chans[order, c])  # the channel's quantiles (linear, as np.quantile)
    gauss[:, 4], gauss[:, 5], gauss[:, 6] = height.ravel(), hx.ravel(), hy.ravel()
    return Exemplar(gauss.reshape(H, W, -1), lut, mean.astype(np.float32), axes.astype(np.float32), float(np.median(contrast)) + 1e-6, float(pixel))


# --------------------------------------------------------------------------------------- synthesis
_SKEW = np.array([[1.0, -1.0 / np.sqrt(3.0)], [0.0, 2.0 / np.sqrt(3.0)]])  # equilateral triangles of edge 1
_UNSKEW = np.linalg.inv(_SKEW)


def _hash2(i: np.ndarray, j: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Two uniform [0, 1) values per integer lattice vertex ``(i, j)`` (int64 arrays) and ``seed``
    (splitmix64 of the packed vertex: the same vertex and seed always give the same values)."""
    with np.errstate(over="ignore"):
        z = (i.astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15)) ^ (j.astype(np.uint64) * np.uint64(0xC2B2AE3D27D4EB4F))
        z = z ^ np.uint64((int(seed) * 0x165667B19E3779F9) & 0xFFFFFFFFFFFFFFFF)
        out = []
        for salt in (0x94D049BB133111EB, 0xBF58476D1CE4E5B9):
            x = z + np.uint64(salt)
            x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
            x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
            x = x ^ (x >> np.uint64(31))
            out.append((x >> np.uint64(11)).astype(np.float64) / float(1 << 53))
    return out[0], out[1]


def quads(image: np.ndarray) -> np.ndarray:
    """``image`` (h, w, C) as ``(h * w, 4, C)``: each pixel with its right, lower and lower-right
    neighbours (the edge repeated), so a bilinear read is one gather (:func:`_bilinear`)."""
    p = np.pad(np.asarray(image, dtype=np.float32), ((0, 1), (0, 1), (0, 0)), mode="edge")
    h, w, c = image.shape
    return np.ascontiguousarray(np.stack([p[:-1, :-1], p[:-1, 1:], p[1:, :-1], p[1:, 1:]], axis=2).reshape(h * w, 4, c))


def _bilinear(q: np.ndarray, shape: tuple[int, int], x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """An image read bilinearly at pixel coordinates ``x`` (columns), ``y`` (rows) (n,), clamped to
    the image: ``q`` its :func:`quads`, ``shape`` its (h, w). Returns (n, C) float32."""
    h, w = shape
    x = np.clip(x, 0.0, w - 1.001)
    y = np.clip(y, 0.0, h - 1.001)
    x0 = x.astype(np.int64)
    y0 = y.astype(np.int64)
    fx = (x - x0).astype(np.float32)[:, None]
    fy = (y - y0).astype(np.float32)[:, None]
    v = q[y0 * w + x0]  # (n, 4, C)
    top = v[:, 0] + (v[:, 1] - v[:, 0]) * fx
    bot = v[:, 2] + (v[:, 3] - v[:, 2]) * fx
    return top + (bot - top) * fy


def tile_blend(ex: Exemplar, uv: np.ndarray, seed: int, channels: list[int]) -> np.ndarray:
    """Histogram-preserving tiling and blending in the plane.

    Args:
        ex: the exemplar.
        uv: ``(n, 2)`` float positions in photo pixels (x along the photo's columns, y along its rows).
        seed: the patches' offsets (same seed: same texture).
        channels: which channels of ``ex.gauss`` to read.
    Returns:
        ``(n, c)`` float32 blended values (unit variance where the channel has it, whatever the
        weights; :func:`from_gauss` takes Gaussianised channels back to the photo's own values).
    """
    uv = np.asarray(uv, dtype=np.float64)
    h, w = ex.shape
    cell = CELL * min(h, w)
    reach = REACH * cell + 1.0
    span = np.array([max(w - 1 - 2 * reach, 0.0), max(h - 1 - 2 * reach, 0.0)])
    skew = (uv / cell) @ _SKEW.T
    base = np.floor(skew)
    frac = (skew - base).astype(np.float32)  # in [0, 1): float32 is exact enough, and faster
    f3 = np.float32(1.0) - frac[:, 0] - frac[:, 1]
    up = f3 <= 0
    upi = up.astype(np.int64)
    bi, bj = base[:, 0].astype(np.int64), base[:, 1].astype(np.int64)
    # the triangle's vertices (skewed lattice) and barycentric weights
    verts = ((bi + upi, bj + upi), (bi + upi, bj + 1 - upi), (bi + 1 - upi, bj + upi))
    wts = (np.abs(f3), np.where(up, 1 - frac[:, 1], frac[:, 1]), np.where(up, 1 - frac[:, 0], frac[:, 0]))
    # a point's place from its vertex: the vertex's own (unskewed) place is a whole number of cells
    # from the base vertex's, so only the fraction is carried (small numbers: float32 is exact enough)
    fx = (frac[:, 0] + np.float32(0.5) * frac[:, 1]) * np.float32(cell)
    fy = frac[:, 1] * np.float32(np.sqrt(3.0) / 2.0 * cell)
    q = ex.quads(channels)
    out = np.zeros((len(uv), len(channels)), np.float32)
    norm = np.zeros(len(uv), np.float32)
    for (vi, vj), wt in zip(verts, wts):
        ox, oy = _hash2(vi, vj, seed)
        di, dj = (vi - bi).astype(np.float32), (vj - bj).astype(np.float32)  # 0 or 1
        dx = fx - (di + np.float32(0.5) * dj) * np.float32(cell)
        dy = fy - dj * np.float32(np.sqrt(3.0) / 2.0 * cell)
        px = (reach + ox * span[0]).astype(np.float32) + dx
        py = (reach + oy * span[1]).astype(np.float32) + dy
        out += _bilinear(q, (h, w), px, py) * wt[:, None]
        norm += wt * wt
    out /= np.sqrt(np.maximum(norm, np.float32(1e-12)))[:, None]
    return out


def from_gauss(ex: Exemplar, g: np.ndarray, channels: list[int]) -> np.ndarray:
    """Gaussian values ``g`` (n, c) of ``channels`` back to the photo's own values (each channel's
    quantile table)."""
    out = np.empty(g.shape, np.float32)
    for k, c in enumerate(channels):
        out[:, k] = np.interp(g[:, k], _GRID, ex.lut[c])
    return out


def to_rgb(ex: Exemplar, colour: np.ndarray) -> np.ndarray:
    """Colour in the photo's principal axes (n, 3) -> sRGB (n, 3) float32 in [0, 1]."""
    return np.clip(colour @ ex.axes + ex.mean, 0.0, 1.0).astype(np.float32)


def synthesise(ex: Exemplar, uv: np.ndarray, seed: int = 0) -> np.ndarray:
    """A texture at plane positions ``uv`` (n, 2) in photo pixels: ``(n, 3)`` float32 sRGB."""
    g = tile_blend(ex, uv, seed, [0, 1, 2])
    return to_rgb(ex, from_gauss(ex, g, [0, 1, 2]))


def tiled(ex: Exemplar, uv: np.ndarray) -> np.ndarray:
    """The photo repeated as tiles (no synthesis): (n, 3) sRGB at ``uv`` in photo pixels. The wrong
    way a naive look would go, kept for the measures that must tell the two apart."""
    h, w = ex.shape
    x, y = np.mod(uv[:, 0], w - 1), np.mod(uv[:, 1], h - 1)
    g = _bilinear(ex.quads(COLOUR), (h, w), x, y)
    return to_rgb(ex, from_gauss(ex, g, [0, 1, 2]))


# ----------------------------------------------------------------------------------------- on parts
@dataclass(frozen=True)
class PhotoLayer:
    """A photo placed on a group: the photo, its physical width (family units; None: half the part's
    longest side), its turn in degrees against the part's long axis, and the strengths of the maps
    made from it (``normal``: the relief's slope, 0 flat; ``roughness``: how far the photo's local
    contrast moves the roughness from the prompt's)."""

    photo: Photo
    scale: float | None = None
    rotate: float = 0.0
    normal: float = 1.0
    roughness: float = 1.0

    def check(self) -> "PhotoLayer":
        if self.scale is not None and not (np.isfinite(self.scale) and 0 < self.scale <= 1e6):
            raise ValueError(f"a photo's scale must be positive and finite, got {self.scale!r}")
        if not np.isfinite(self.rotate) or abs(self.rotate) > 1e6:
            raise ValueError(f"a photo's rotation is degrees, got {self.rotate!r}")
        for k in ("normal", "roughness"):
            v = getattr(self, k)
            if not (np.isfinite(v) and 0.0 <= v <= 10.0):
                raise ValueError(f"the {k} strength must be within [0, 10], got {v!r}")
        return self


@dataclass
class _Bound:
    """A photo bound to one group: the exemplar, the group's frame (centre (3,), axes (3, 3) rows,
    longest first) and the in-plane turn."""

    ex: Exemplar
    layer: PhotoLayer
    centre: np.ndarray
    axes: np.ndarray
    turn: np.ndarray
    seed: int
    scale: float


@dataclass
class PhotoPainter:
    """A surface painter that paints the groups given a photo from it and the rest as ``surface`` (a
    :class:`proctex.texture.painters.SurfacePainter`) does. Metalness always comes from the prompt's
    words (``surface``); colour, roughness and relief of a photo's groups from the photo.

    Args:
        surface: the prompt's painter (the groups without a photo, and the metalness of every group).
        photos: group index -> :class:`PhotoLayer`.
        seed: the synthesis seed.
        texture_size: the texture's side (the texel footprint the photos are prefiltered for).
    """

    surface: Any
    photos: Mapping[int, PhotoLayer]
    seed: int = 0
    texture_size: int = 512

    _bound: dict[int, _Bound] = field(default_factory=dict)
    _notes: list[str] = field(default_factory=list)
    _kept: dict[tuple, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    _lock: Any = field(default_factory=threading.Lock)
    _frame: tuple[np.ndarray, float] | None = None

    @property
    def blend_groups(self) -> set[int]:
        """The photographed groups: :func:`proctex.texture.paint.paint_surface` and
        :func:`~proctex.texture.paint.paint_material_maps` give their texels a smooth normal field
        (:func:`proctex.texture.paint.blend_normals`) rather than face normals, so the tri-planar
        weights vary continuously across faces, creases and UV seams, and paint a ring of texels
        past their charts; the other groups are painted exactly as the prompt alone paints them."""
        return set(self.photos)

    def bind(self, shape, grouping, up: str = "z", parts=None) -> "PhotoPainter":
        """Place each photo on its group's representative part (frame, scale, prefiltering)."""
        from proctex.texture.paint import shape_frame

        self.surface.bind(shape, grouping, up, parts=parts)
        self._frame = shape_frame(shape)
        self._bound = {}
        groups = {g.index: g for g in grouping.groups}
        for gi, layer in self.photos.items():
            if gi not in groups:
                raise ValueError(f"a photo is given for group {gi}; the shape's groups are 0..{len(groups) - 1}")
            layer.check()
            rep = grouping.parts[groups[gi].representative]
            v = np.asarray(shape.vertices[rep.vertices], dtype=np.float64)
            centre = v.mean(axis=0)
            _, s, vt = np.linalg.svd(v - centre, full_matrices=False)
            axes = _right_handed(vt)
            extent = np.ptp((v - centre) @ axes.T, axis=0)
            scale = float(layer.scale) if layer.scale is not None else max(float(extent.max()), 1e-9) / 2.0
            H, W = layer.photo.rgb.shape[:2]
            area = _area(shape.vertices, shape.faces[rep.faces])
            texel = np.sqrt(max(area, 1e-18) / (0.6 * self.texture_size**2))  # about 60 % of an atlas is covered
            ex = prepare(layer.photo, scale / W, texel)
            a = np.deg2rad(layer.rotate)
            turn = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
            self._bound[gi] = _Bound(ex, layer, centre, axes, turn, int(self.seed) * 1000003 + 7919 * gi, scale)
            how = "given" if layer.scale is not None else "half the part's longest side"
            self._notes.append(
                f"group {gi}: photo {layer.photo.name!r} {W} x {H} px spans {scale:.4g} units ({how}), "
                f"turned {layer.rotate:g} deg, synthesised at {ex.shape[1]} x {ex.shape[0]} px" + "".join(f"; {n}" for n in layer.photo.notes)
            )
        return self

    # the SurfacePainter interface the paint loop and the looks use
    def spec_for(self, group: int | None = None, label: str = ""):
        return self.surface.spec_for(group, label)

    def region_notes(self) -> list[str]:
        return self.surface.region_notes()

    def notes(self) -> list[str]:
        return [*self.surface.notes(), *self._notes]

    def _world(self, points: np.ndarray) -> np.ndarray:
        if self._frame is None:
            raise ValueError("bind the photo painter to its shape first")
        centre, radius = self._frame
        return np.asarray(points, dtype=np.float64) * radius + centre

    def _fields(self, b: _Bound, points: np.ndarray, normals: np.ndarray, colour: bool = True) -> tuple[np.ndarray | None, np.ndarray, np.ndarray]:
        """The photo at world ``points`` with ``normals``, tri-planar: the three planes across the
        part's axes weighted |n_k|^SHARP (weights below 1 % dropped), each plane's values blended
        keeping the variance. Returns ``(rgb (n, 3) or None without colour, contrast (n,), height
        gradient (n, 3) per unit length in photo-pixel heights)``: the gradient of each plane turned
        back to its two part axes before the planes are blended. The normals are the smooth ones
        (:attr:`blend_groups`), so the weights are continuous wherever the surface is."""
        local = (points - b.centre) @ b.axes.T / b.ex.pixel  # photo pixels along the part's axes
        along = np.asarray(normals, dtype=np.float64) @ b.axes.T
        wts = np.abs(along) ** SHARP
        wts /= np.maximum(wts.sum(axis=1, keepdims=True), 1e-12)
        wts[wts < 0.01] = 0.0
        norm = np.sqrt(np.maximum((wts**2).sum(axis=1), 1e-12))
        channels = [*(COLOUR if colour else []), *CONTRAST, 5, 6]
        vals = np.zeros((len(points), len(channels)), np.float32)
        grad = np.zeros((len(points), 3))
        for k, (i, j) in enumerate(((0, 1), (0, 2), (1, 2))):  # planes across axes 2, 1, 0
            wk = wts[:, 2 - k]
            sel = np.flatnonzero(wk > 0)
            if not len(sel):
                continue
            uv = local[sel][:, [i, j]] @ b.turn.T
            # the two sides of a plane (a box's top and bottom) get their own patches, or each would
            # show the other's texture; the side flips only where the plane's weight is nil
            back = along[sel, 2 - k] < 0
            got = np.empty((len(sel), len(channels)), np.float32)
            for side in (False, True):
                at = back == side
                if at.any():
                    got[at] = tile_blend(b.ex, uv[at], b.seed + 101 * k + 53 * side, channels)
            scale = wk[sel] / norm[sel]
            vals[sel] += got * scale[:, None].astype(np.float32)
            g2 = np.asarray(got[:, -2:], dtype=np.float64) @ b.turn  # d/d(local i, local j) of this plane's height
            grad[sel] += scale[:, None] * (g2[:, :1] * b.axes[i] + g2[:, 1:2] * b.axes[j])
        rgb = to_rgb(b.ex, from_gauss(b.ex, vals[:, :3], COLOUR)) if colour else None
        contrast = from_gauss(b.ex, vals[:, -3:-2], CONTRAST)[:, 0]
        return rgb, contrast, grad

    @staticmethod
    def _key(points: np.ndarray) -> tuple:
        """A fingerprint of a point array (its length and sums): the maps ask for the texels the
        colour was painted at, with the same values."""
        return (len(points), float(points.sum()), float(np.abs(points).sum()), float(points[:1].sum()), float(points[-1:].sum()))

    def paint(self, points: np.ndarray, normals: np.ndarray, group: int | None = None, label: str = "", text: str | None = None) -> np.ndarray:
        """Colours (n, 3) float32 of points (normalised frame) of ``group``: from its photo, else the
        prompt's. A photo's contrast and relief at the same points are kept for :meth:`material`
        (one synthesis for both)."""
        b = self._bound.get(group) if text is None and group is not None else None
        if b is None:
            return self.surface.paint(points, normals, group=group, label=label, text=text)
        pts, nrm = _checked(points, normals)
        out = np.empty((len(pts), 3), np.float32)
        contrast = np.empty(len(pts), np.float32)
        grad = np.empty((len(pts), 3))
        for s in range(0, len(pts), CHUNK):
            sl = slice(s, s + CHUNK)
            out[sl], contrast[sl], grad[sl] = self._fields(b, self._world(pts[sl]), nrm[sl])
        with self._lock:  # groups are painted side by side (proctex.texture.paint.per_group)
            self._kept[(group, self._key(pts))] = (contrast, grad.astype(np.float32))
            while sum(c.nbytes + g.nbytes for c, g in self._kept.values()) > KEEP_BYTES:  # the oldest go first
                self._kept.pop(next(iter(self._kept)))
        return out

    def material(
        self, points: np.ndarray, normals: np.ndarray, tangents: np.ndarray, bitangents: np.ndarray, group: int | None = None, label: str = "", blend: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(roughness (n,), metallic (n,), normal (n, 3))`` as :meth:`SurfacePainter.material`
        (``blend``: the normals the projections follow, as :meth:`paint` got them; default
        ``normals``): for a photo's group the roughness is the prompt's moved by the photo's local
        contrast (``roughness`` strength 1: up to 0.3 either way, rougher where the photo's local
        contrast is above its median), the relief is the photo's height (``normal`` strength: its
        slope, with the height's spread at half a photo pixel), and the metalness is the prompt's alone."""
        b = self._bound.get(group) if group is not None else None
        if b is None:
            return self.surface.material(points, normals, tangents, bitangents, group=group, label=label)
        rough, metal, _ = self.surface.material(points, normals, tangents, bitangents, group=group, label=label, relief=False)
        pts, nrm = _checked(points, normals if blend is None else blend)
        tan = np.asarray(tangents, dtype=np.float64)
        bit = np.asarray(bitangents, dtype=np.float64)
        with self._lock:
            kept = self._kept.pop((group, self._key(pts)), None)
        if kept is None:
            contrast, grad = np.empty(len(pts), np.float32), np.empty((len(pts), 3))
            for s in range(0, len(pts), CHUNK):
                sl = slice(s, s + CHUNK)
                _, contrast[sl], grad[sl] = self._fields(b, self._world(pts[sl]), nrm[sl], colour=False)
        else:
            contrast, grad = kept[0], kept[1].astype(np.float64)
        rough = np.clip(np.asarray(rough, np.float32) + b.layer.roughness * 0.3 * np.tanh(2.0 * (contrast / b.ex.contrast - 1.0)), 0.02, 1.0).astype(np.float32)
        grad = grad * (0.5 * b.layer.normal)  # heights spread half a photo pixel: the slope is dimensionless
        dt = np.einsum("kd,kd->k", grad, tan)
        db = np.einsum("kd,kd->k", grad, bit)
        nt = np.stack([-dt, -db, np.ones(len(dt))], axis=1)
        nts = (nt / np.linalg.norm(nt, axis=1, keepdims=True)).astype(np.float32)
        return rough, np.asarray(metal, np.float32), nts


def _right_handed(vt: np.ndarray) -> np.ndarray:
    """Principal axes (3, 3) rows, longest first, each pointing to its positive majority direction
    (the sign of its largest component positive) and forming a right-handed frame."""
    axes = np.array(vt, dtype=np.float64)
    for k in range(3):
        if axes[k, np.argmax(np.abs(axes[k]))] < 0:
            axes[k] = -axes[k]
    if np.linalg.det(axes) < 0:
        axes[2] = -axes[2]
    return axes


def _area(vertices: np.ndarray, faces: np.ndarray) -> float:
    v = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]
    return float(0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1).sum())


def _checked(points: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    pts = np.asarray(points, dtype=np.float64)
    nrm = np.asarray(normals, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or nrm.shape != pts.shape:
        raise ValueError(f"points and normals must be (n, 3) alike, got {pts.shape} and {nrm.shape}")
    if not (np.isfinite(pts).all() and np.isfinite(nrm).all()):
        raise ValueError("points and normals must be finite")
    return pts, nrm


# ------------------------------------------------------------------------------ the paint settings
#: the most photos one look may name.
MAX_IMAGES = 64
#: what a photo entry of :attr:`proctex.texture.painting.PaintConfig.images` may hold.
_ENTRY_KEYS = {"file", "scale", "rotate", "normal", "roughness", "sha256", "name", "notes", "units", "under_prompt"}


def check_images(images: Any) -> dict[str, dict[str, Any]]:
    """The ``images`` of paint settings, checked: ``{key: entry}`` with at most :data:`MAX_IMAGES`
    keys (a group number, label or part word of at most 200 characters, or ``"*"``) and entries
    ``{"file": str, "scale": positive number or None, "rotate": degrees, "normal": [0, 10],
    "roughness": [0, 10]}`` (and the record's ``sha256``, ``name``, ``notes``, ``units``,
    ``under_prompt``). Returns a normalised copy; ``ValueError`` names what is wrong."""
    if not isinstance(images, Mapping):
        raise ValueError("images must be an object {part: photo}")
    if len(images) > MAX_IMAGES:
        raise ValueError(f"a look takes at most {MAX_IMAGES} photos, got {len(images)}")
    out: dict[str, dict[str, Any]] = {}
    for key, entry in images.items():
        if not isinstance(key, str) or not key.strip() or len(key) > 200:
            raise ValueError(f"a photo's part is a group number, label or part word of 1-200 characters, got {str(key)[:40]!r}")
        if not isinstance(entry, Mapping):
            raise ValueError(f"photo {key[:40]!r}: an entry is an object with its file, got {type(entry).__name__}")
        extra = set(entry) - _ENTRY_KEYS
        if extra:
            raise ValueError(f"photo {key[:40]!r}: unknown settings {', '.join(sorted(map(str, extra)))[:120]}")
        f = entry.get("file")
        if not isinstance(f, str) or not f or len(f) > 4096:
            raise ValueError(f"photo {key[:40]!r}: its file must be a path")
        scale = entry.get("scale")
        if scale is not None:
            scale = parse_length(scale)
        e = {"file": f, "scale": scale, "rotate": _number(entry.get("rotate", 0.0), f"photo {key[:40]!r}: rotate", -1e6, 1e6)}
        for k in ("normal", "roughness"):
            e[k] = _number(entry.get(k, 1.0), f"photo {key[:40]!r}: the {k} strength", 0.0, 10.0)
        for k in ("sha256", "name", "units"):
            if k in entry:
                if not isinstance(entry[k], str) or len(entry[k]) > 400:
                    raise ValueError(f"photo {key[:40]!r}: {k} must be a short string")
                e[k] = entry[k]
        if "notes" in entry:
            notes = entry["notes"]
            if not isinstance(notes, (list, tuple)) or len(notes) > 32 or not all(isinstance(n, str) and len(n) <= 400 for n in notes):
                raise ValueError(f"photo {key[:40]!r}: notes must be a short list of strings")
            e["notes"] = list(notes)
        if "under_prompt" in entry:
            if not isinstance(entry["under_prompt"], bool):
                raise ValueError(f"photo {key[:40]!r}: under_prompt must be true or false")
            e["under_prompt"] = entry["under_prompt"]
        out[key] = e
    return out


def _number(v: Any, what: str, lo: float, hi: float) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or not lo <= v <= hi:
        raise ValueError(f"{what} must be a number within [{lo:g}, {hi:g}], got {str(v)[:40]!r}")
    return float(v)


def layers(images: Mapping[str, Mapping[str, Any]], photos: Mapping[str, Photo] | None = None, read: Any = None) -> dict[str, PhotoLayer]:
    """The :class:`PhotoLayer` of each checked ``images`` entry: its photo from ``photos`` (by key)
    or read from its file (``read(path) -> bytes``, default the file system)."""
    out = {}
    for key, e in images.items():
        if photos is not None and key in photos:
            photo = photos[key]
        else:
            photo = read_photo(read(e["file"]) if read is not None else e["file"], name=e.get("name") or Path(e["file"]).name)
        out[key] = PhotoLayer(photo, e.get("scale"), float(e.get("rotate", 0.0)), float(e.get("normal", 1.0)), float(e.get("roughness", 1.0))).check()
    return out
