"""Watertight mesh primitives with canonical coordinates, for the built-in procedural models.

Every primitive returns a :class:`Part`: ``vertices (n, 3) float64``, ``faces (m, 3) int64`` with
outward-facing winding, and ``canonical (n, 3) float64``. Canonical coordinates are a continuous
embedding of the part's parameter domain that does not depend on the model's parameters, so the same
canonical point means the same surface point across a family (docs/correspondence.md):

- boxes: the normalised position inside the box, in ``[0, 1]^3``;
- ring surfaces (surfaces of revolution, swept tubes): a point on the unit sphere,
  ``(sin(pi s) cos(phi), sin(pi s) sin(phi), cos(pi s))`` with ``s`` in ``[0, 1]`` the profile
  parameter chosen by the caller (0 and 1 are the poles) and ``phi`` the angle around the axis.

Transforms keep the canonical coordinates; a mirror flips the winding so normals stay outward.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from proctex.geometry.rowmath import cross3


@dataclass
class Part:
    """One connected, closed surface.

    Attributes:
        vertices: (n, 3) float64 positions.
        faces: (m, 3) int64 vertex indices, counter-clockwise seen from outside.
        canonical: (n, 3) float64 canonical coordinates (see module docstring).
    """

    vertices: np.ndarray
    faces: np.ndarray
    canonical: np.ndarray

    def copy(self) -> "Part":
        return Part(self.vertices.copy(), self.faces.copy(), self.canonical.copy())


def signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Signed volume enclosed by a closed triangle mesh (positive when normals face outward)."""
    a, b, c = vertices[faces[:, 0]], vertices[faces[:, 1]], vertices[faces[:, 2]]
    return float(np.einsum("ij,ij->i", a, cross3(b, c)).sum() / 6.0)


def _orient_outward(part: Part) -> Part:
    if signed_volume(part.vertices, part.faces) < 0:
        part.faces = part.faces[:, ::-1].copy()
    return part


# ------------------------------------------------------------------------------------ resolution
def segment_count(length: float, edge: float, minimum: int = 1) -> int:
    """Segments along ``length`` (m) for a target ``edge`` length (m): ``max(minimum, round(length / edge))``.

    Raises ``ValueError`` unless ``length >= 0``, ``edge > 0`` (both finite) and ``minimum >= 1``.
    """
    length, edge = float(length), float(edge)
    if not (np.isfinite(length) and length >= 0 and np.isfinite(edge) and edge > 0) or int(minimum) < 1:
        raise ValueError(f"segment_count needs length >= 0, edge > 0 and minimum >= 1, got {length}, {edge}, {minimum}")
    return max(int(minimum), int(round(length / edge)))


def _box_edges(size: np.ndarray, edge: float, rings_per_width: float = 2.0) -> np.ndarray:
    """Target edge (m) per axis (3,) of a box of ``size`` (3,): ``edge``, except along the longest
    axis, where it is capped at the middle dimension over ``rings_per_width`` (> 0), so a bar gets
    at least that many rings per width along its length (bending, tapering and curling warps stay
    smooth) and its ring count follows its thickness as well as its length."""
    if not rings_per_width > 0:
        raise ValueError(f"rings_per_width must be > 0, got {rings_per_width}")
    edges = np.full(3, float(edge))
    order = np.argsort(size, kind="stable")
    edges[order[2]] = min(float(edge), float(size[order[1]]) / rings_per_width)
    return edges


def box_divisions(size: Sequence[float], edge: float, minimum: Sequence[int] | int = 1, rings_per_width: float = 2.0) -> tuple[int, int, int]:
    """Segments (3,) of a box of ``size`` (3,) for a target ``edge`` length (m): ``max(minimum,
    round(size / edge))`` per axis, with the edge along the longest axis capped at the middle
    dimension over ``rings_per_width`` (see :func:`_box_edges`)."""
    size = np.asarray(size, dtype=float)
    if size.shape != (3,) or np.any(size <= 0) or not np.all(np.isfinite(size)):
        raise ValueError(f"box size must be three positive finite numbers, got {size}")
    mins = np.broadcast_to(np.asarray(minimum, dtype=int), (3,))
    edges = _box_edges(size, edge, rings_per_width)
    return tuple(segment_count(size[a], edges[a], int(mins[a])) for a in range(3))  # type: ignore[return-value]


def ring_points(radius: float, edge: float, minimum: int = 8, multiple: int = 1) -> int:
    """Points per ring of a circle of ``radius`` (m) for a target ``edge`` (m): a multiple of
    ``multiple``, at least ``minimum``."""
    if int(multiple) < 1:
        raise ValueError(f"multiple must be >= 1, got {multiple}")
    n = segment_count(2 * np.pi * float(radius) / int(multiple), edge, max(1, -(-int(minimum) // int(multiple))))
    return n * int(multiple)


def revolve_resolution(radius: float, edge: float, minimum: int = 8, multiple: int = 1) -> tuple[int, float]:
    """Points per ring (see :func:`ring_points`) of a surface of revolution whose widest ring has
    ``radius`` (m), and the spacing (m) to use along its profile: ``edge`` capped by the ring's own
    edge length, so thin parts get roughly square quads."""
    n = ring_points(radius, edge, minimum, multiple)
    return n, min(float(edge), 2 * np.pi * float(radius) / n)


def split_spans(knots: Sequence[float], counts: Sequence[int]) -> np.ndarray:
    """Values (sum(counts) + 1,) float64: interval ``[knots[i], knots[i + 1]]`` cut into ``counts[i]``
    equal pieces; every knot is hit exactly. ``knots`` (k + 1,) strictly increasing, ``counts`` (k,) >= 1."""
    knots = np.asarray(knots, dtype=float)
    counts = np.asarray(counts, dtype=int)
    if knots.ndim != 1 or len(knots) < 2 or counts.shape != (len(knots) - 1,) or np.any(counts < 1):
        raise ValueError(f"split_spans needs k + 1 knots and k counts >= 1, got {knots} and {counts}")
    if np.any(np.diff(knots) <= 0):
        raise ValueError(f"knots must be strictly increasing, got {knots}")
    pieces = [knots[i] + (knots[i + 1] - knots[i]) * np.arange(c) / c for i, c in enumerate(counts)]
    return np.concatenate(pieces + [knots[-1:]])


def resample(points: np.ndarray, s: np.ndarray, s_new: np.ndarray) -> np.ndarray:
    """Piecewise-linear interpolation of ``points`` (K, d) given at increasing parameters ``s`` (K,)
    at ``s_new`` (n,): (n, d) float64."""
    points = np.asarray(points, dtype=float)
    s = np.asarray(s, dtype=float)
    if points.ndim != 2 or s.shape != (len(points),) or np.any(np.diff(s) <= 0):
        raise ValueError("resample needs (K, d) points at strictly increasing (K,) parameters")
    return np.stack([np.interp(s_new, s, points[:, j]) for j in range(points.shape[1])], axis=1)


def uniform_s(n_fixed: int, u: np.ndarray) -> np.ndarray:
    """Profile parameters (k,) of the default convention ``s_k = (k + 1) / (K + 1)`` for ``K =
    n_fixed`` rings at ``u = k / (K - 1)``, at any curve parameters ``u`` (k,) in [0, 1].

    A curve sampled at ``K`` uniform ``u`` in fixed mode keeps the same canonical parametrisation
    when it is sampled at any other ``u``.
    """
    if int(n_fixed) < 2:
        raise ValueError(f"n_fixed must be >= 2, got {n_fixed}")
    return (np.asarray(u, dtype=float) * (n_fixed - 1) + 1.0) / (n_fixed + 1.0)


def polyline_length(points: np.ndarray) -> float:
    """Length (m) of the polyline through ``points`` (k, d)."""
    points = np.asarray(points, dtype=float)
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum()) if len(points) > 1 else 0.0


def curve_parameters(
    curve: Callable[[np.ndarray], np.ndarray],
    knots: Sequence[float],
    edge: float,
    minimum: Sequence[int] | int = 1,
    dense: int = 64,
) -> np.ndarray:
    """Curve parameters (k,) float64 for an adaptive sampling of ``curve``.

    Each interval ``[knots[i], knots[i + 1]]`` is cut into ``max(minimum[i], round(length / edge))``
    equal parameter steps, its length measured on ``dense`` samples; the knots themselves are kept.

    Args:
        curve: ``f(u (n,)) -> points (n, d)``.
        knots: (k + 1,) strictly increasing curve parameters (corners, ends).
    """
    knots = np.asarray(knots, dtype=float)
    mins = np.broadcast_to(np.asarray(minimum, dtype=int), (len(knots) - 1,))
    counts = [segment_count(polyline_length(curve(np.linspace(a, b, dense))), edge, int(m)) for a, b, m in zip(knots[:-1], knots[1:], mins)]
    return split_spans(knots, counts)


def subdivide_profile(radius: np.ndarray, height: np.ndarray, s: np.ndarray, z_bottom: float, z_top: float, edge: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Profile with every span cut into ``max(1, round(length / edge))`` equal pieces.

    The spans are pole -> first ring, ring -> ring and last ring -> pole, with the poles on the axis
    at ``z_bottom`` / ``z_top`` (s = 0 / 1). The input rings are kept; new rings and their ``s`` are
    linear interpolations, so the surface and its canonical parametrisation are unchanged.

    Args:
        radius, height, s: (K,) float64 profile (as for :func:`revolve`).
    Returns:
        ``(radius, height, s)``, each (K',) float64 with K' >= K.
    """
    radius, height, s = (np.asarray(a, dtype=float) for a in (radius, height, s))
    pts = np.concatenate([[[0.0, z_bottom]], np.stack([radius, height], axis=1), [[0.0, z_top]]])
    knots = np.concatenate([[0.0], s, [1.0]])
    lengths = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    counts = [segment_count(length, edge, 1) for length in lengths]
    s_new = split_spans(knots, counts)[1:-1]
    out = resample(pts, knots, s_new)
    return out[:, 0], out[:, 1], s_new


# ---------------------------------------------------------------------------------------------- boxes
def _axis_lattice(divisions: int | Sequence[float], axis: int) -> np.ndarray:
    """Canonical lattice values (k + 1,) float64 of one box axis: ``k`` uniform segments for an
    integer, else the given values (sorted, from 0 to 1)."""
    if np.ndim(divisions) == 0:
        n = int(divisions)
        if n < 1 or n != divisions:
            raise ValueError(f"box divisions along axis {axis} must be an integer >= 1, got {divisions}")
        return np.arange(n + 1) / n
    c = np.asarray(divisions, dtype=float)
    if c.ndim != 1 or len(c) < 2 or c[0] != 0.0 or c[-1] != 1.0 or np.any(np.diff(c) <= 0):
        raise ValueError(f"box lattice along axis {axis} must increase strictly from 0 to 1, got {divisions}")
    return c


def box(
    size: Sequence[float],
    center: Sequence[float] = (0.0, 0.0, 0.0),
    divisions: Sequence[int | Sequence[float]] = (1, 1, 1),
    warp: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
) -> Part:
    """Closed, subdivided axis-aligned box.

    Args:
        size: (3,) edge lengths (> 0).
        center: (3,) centre.
        divisions: per axis (x, y, z) either a number of uniform segments (>= 1) or the canonical
            lattice values (k + 1,) in [0, 1], strictly increasing from 0 to 1.
        warp: optional ``f(local, canonical) -> local`` applied to the centred positions
            ``local (n, 3)`` before translation; used to taper, bevel or bend a box while keeping
            its canonical coordinates.

    Returns:
        Part with canonical = normalised position in the box, in [0, 1]^3.
    """
    size = np.asarray(size, dtype=float)
    if size.shape != (3,) or np.any(size <= 0) or not np.all(np.isfinite(size)):
        raise ValueError(f"box size must be three positive finite numbers, got {size}")
    if isinstance(divisions, (str, bytes)) or len(divisions) != 3:
        raise ValueError(f"box divisions must be given for three axes, got {divisions}")
    axes = [_axis_lattice(d, a) for a, d in enumerate(divisions)]
    div = np.array([len(c) - 1 for c in axes])
    nx, ny, nz = div
    # Vertex id for every lattice point on the boundary of the (nx+1, ny+1, nz+1) grid.
    ids = -np.ones((nx + 1, ny + 1, nz + 1), dtype=np.int64)
    i, j, k = np.meshgrid(np.arange(nx + 1), np.arange(ny + 1), np.arange(nz + 1), indexing="ij")
    on = (i == 0) | (i == nx) | (j == 0) | (j == ny) | (k == 0) | (k == nz)
    ids[on] = np.arange(int(on.sum()))
    canonical = np.stack([axes[0][i[on]], axes[1][j[on]], axes[2][k[on]]], axis=1)
    faces = []

    def quads(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray) -> None:
        faces.append(np.stack([a, b, c], axis=-1).reshape(-1, 3))
        faces.append(np.stack([a, c, d], axis=-1).reshape(-1, 3))

    for axis in range(3):
        u, v = [ax for ax in range(3) if ax != axis]
        for side in (0, div[axis]):
            sl = [slice(None)] * 3
            sl[axis] = side
            g = ids[tuple(sl)]  # 2D grid over (u, v)
            a, b, c, d = g[:-1, :-1], g[1:, :-1], g[1:, 1:], g[:-1, 1:]
            quads(a, b, c, d)
    f = np.concatenate(faces).astype(np.int64)
    local = (canonical - 0.5) * size
    if warp is not None:
        local = np.asarray(warp(local.copy(), canonical.copy()), dtype=float)
    if not np.all(np.isfinite(local)) or local.shape != canonical.shape:
        raise ValueError("box warp must return finite (n, 3) positions")
    # Orient every face outward on the unwarped (convex) lattice, then check the warp kept it.
    unwarped = (canonical - 0.5) * size
    tri = unwarped[f]
    n = cross3(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    outward = np.einsum("ij,ij->i", n, tri.mean(axis=1)) > 0
    f = np.where(outward[:, None], f, f[:, ::-1])
    part = Part(local + np.asarray(center, dtype=float), f, canonical.astype(float))
    return _orient_outward(part)


def _graded_axis(c: np.ndarray, half: float, band_lo: float, band_hi: float, knot_lo: float, knot_hi: float) -> np.ndarray:
    """Positions (k,) along one box axis for lattice canonical coordinates ``c`` (k,) in [0, 1].

    Canonical ``[0, knot_lo]`` / ``[knot_hi, 1]`` cover the rounding bands ``band_lo`` / ``band_hi``
    (0: no band, uniform spacing there); the rest of the axis is linear in between.
    """
    knots_c, knots_x = [0.0], [-half]
    if band_lo > 0:
        knots_c.append(knot_lo)
        knots_x.append(-half + band_lo)
    if band_hi > 0:
        knots_c.append(knot_hi)
        knots_x.append(half - band_hi)
    knots_c.append(1.0)
    knots_x.append(half)
    return np.interp(c, knots_c, knots_x)


def rounded_box(
    size: Sequence[float],
    center: Sequence[float] = (0.0, 0.0, 0.0),
    divisions: Sequence[int] = (4, 4, 4),
    round_lo: Sequence[float] = (0.0, 0.0, 0.0),
    round_hi: Sequence[float] = (0.0, 0.0, 0.0),
    edge_segments: int = 2,
    warp: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
    middle: Sequence[int] | None = None,
) -> Part:
    """Box whose chosen sides have rounded edges, optionally warped afterwards.

    Args:
        size: (3,) edge lengths.
        center: (3,) centre (applied after ``warp``).
        divisions: (3,) lattice segments; an axis with rounding on one side needs at least
            ``edge_segments + 1``, on both sides ``2 * edge_segments + 1``. A rounding band covers
            the canonical extent ``edge_segments / divisions`` of its axis.
        round_lo, round_hi: (3,) rounding radius of the edges bounding the low / high face along
            each axis (0 keeps that face sharp). An edge is rounded where both faces meeting there
            have a radius, e.g. ``round_hi = (r, 0, r)`` rounds only the (+x, +z) edge.
        edge_segments: lattice segments across each rounding band.
        warp: optional ``f(local (n, 3), canonical (n, 3)) -> local`` applied after rounding.
        middle: optional (3,) segments (>= 1) between the rounding bands (adaptive tessellation).
            The bands keep their canonical extent and ``edge_segments`` segments, so the canonical
            coordinates mean the same surface points whatever ``middle`` is. ``None``: the
            ``divisions`` lattice.

    The rounding maps each corner region of the box onto a quarter disc (or ball octant) by
    scaling the offset ``d`` from the inner box by ``max|d_i| / |d|``, which fixes the flat faces
    and keeps the map one-to-one, so canonical coordinates stay the box's.
    """
    size = np.asarray(size, dtype=float)
    half = size / 2
    lo, hi = np.asarray(round_lo, dtype=float), np.asarray(round_hi, dtype=float)
    div = np.asarray(divisions, dtype=int)
    need = 1 + edge_segments * ((lo > 0).astype(int) + (hi > 0).astype(int))
    if np.any(div < need) or np.any(lo + hi >= size):
        raise ValueError(f"rounded_box: divisions {div} or radii lo={lo} hi={hi} do not fit size {size}")
    knot_lo = [edge_segments / div[a] for a in range(3)]
    knot_hi = [1.0 - edge_segments / div[a] for a in range(3)]

    def _round(local: np.ndarray, canonical: np.ndarray) -> np.ndarray:
        pos = np.stack([_graded_axis(canonical[:, a], half[a], lo[a], hi[a], knot_lo[a], knot_hi[a]) for a in range(3)], axis=1)
        inner = np.clip(pos, -half + lo, half - hi)
        d = pos - inner
        norm = np.linalg.norm(d, axis=1, keepdims=True)
        scale = np.divide(np.abs(d).max(axis=1, keepdims=True), norm, out=np.ones_like(norm), where=norm > 0)
        out = inner + d * scale
        return out if warp is None else warp(out, canonical)

    if middle is None:
        return box(size, center, div, _round)
    mid = np.asarray(middle, dtype=int)
    if mid.shape != (3,) or np.any(mid < 1):
        raise ValueError(f"rounded_box: middle must be three integers >= 1, got {middle}")
    lattice = []
    for a in range(3):
        knots, counts = [0.0], []
        if lo[a] > 0:
            knots.append(knot_lo[a])
            counts.append(edge_segments)
        if hi[a] > 0:
            knots.append(knot_hi[a])
            counts.append(int(mid[a]))
        knots.append(1.0)
        counts.append(edge_segments if hi[a] > 0 else int(mid[a]))
        lattice.append(split_spans(knots, counts))
    return box(size, center, lattice, _round)


def rounded_box_middle(
    size: Sequence[float],
    round_lo: Sequence[float],
    round_hi: Sequence[float],
    edge: float,
    minimum: Sequence[int] | int = 1,
    rings_per_width: float = 2.0,
) -> tuple[int, int, int]:
    """Adaptive ``middle`` segments (3,) of a :func:`rounded_box`: the flat length between the
    rounding bands of each axis over the target ``edge`` (per axis as in :func:`box_divisions`)."""
    size = np.asarray(size, dtype=float)
    flat = size - np.asarray(round_lo, dtype=float) - np.asarray(round_hi, dtype=float)
    if np.any(flat <= 0):
        raise ValueError(f"rounding radii lo={round_lo} hi={round_hi} do not fit size {size}")
    mins = np.broadcast_to(np.asarray(minimum, dtype=int), (3,))
    edges = _box_edges(size, edge, rings_per_width)
    return tuple(segment_count(flat[a], edges[a], int(mins[a])) for a in range(3))  # type: ignore[return-value]


def translated(part: Part, offsets: Sequence[Sequence[float]]) -> list[Part]:
    """Copies of ``part`` translated by each (3,) offset."""
    return [transform(part, t=o) for o in offsets]


# ---------------------------------------------------------------------------------------- transforms
def rotation(axis: str | Sequence[float], angle: float) -> np.ndarray:
    """(3, 3) rotation matrix about ``'x'``, ``'y'``, ``'z'`` or a given axis vector (radians)."""
    if isinstance(axis, str):
        axis = {"x": (1, 0, 0), "y": (0, 1, 0), "z": (0, 0, 1)}[axis]
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def transform(part: Part, R: np.ndarray | None = None, t: Sequence[float] | None = None, scale: float | Sequence[float] = 1.0) -> Part:
    """New part with vertices ``R @ (scale * v) + t``; canonical coordinates are kept."""
    v = part.vertices * np.asarray(scale, dtype=float)
    if R is not None:
        v = v @ np.asarray(R, dtype=float).T
    if t is not None:
        v = v + np.asarray(t, dtype=float)
    out = Part(v, part.faces.copy(), part.canonical.copy())
    if np.prod(np.sign(np.broadcast_to(np.asarray(scale, float), (3,)))) * (np.linalg.det(R) if R is not None else 1) < 0:
        out.faces = out.faces[:, ::-1].copy()
    return out


def mirror(part: Part, axis: int = 0, plane: float = 0.0) -> Part:
    """Reflection of a part across the plane ``x[axis] = plane``; winding flipped, canonical kept."""
    v = part.vertices.copy()
    v[:, axis] = 2 * plane - v[:, axis]
    return Part(v, part.faces[:, ::-1].copy(), part.canonical.copy())


def with_box_canonical(part: Part) -> Part:
    """The part with canonical = normalised position in its bounding box, in [0, 1]^3.

    For parts that a family builds with different primitives (a round or a rectangular table
    top), so their canonical coordinates stay comparable with a box's.
    """
    lo, hi = part.vertices.min(axis=0), part.vertices.max(axis=0)
    canon = (part.vertices - lo) / np.maximum(hi - lo, 1e-300)
    return Part(part.vertices.copy(), part.faces.copy(), canon)
