"""Per-face UVs into the template textures from a part's mapped vertices (:func:`part_uvs`), with the
side test for thin walls and the run-time coverage check that proves each face reads only its
chart (:func:`_inside_chart`; step 4 of :mod:`proctex.transfer.apply`)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from proctex.geometry.rowmath import dot3
from proctex.texture.inpaint import chart_labels
from proctex.texture.pbr import area_normals
from proctex.transfer.assets import GroupAssets, TemplateAssets


def _affine_frames(tri: np.ndarray) -> tuple[np.ndarray, ...]:
    """What :func:`_affine_uv` needs of triangles ``tri (k, 3, 3)``, computed once for all three
    corners: ``(a, e1, e2, d11, d12, d22, den)``, ``den`` inf for a degenerate triangle."""
    a = tri[:, 0]
    e1, e2 = tri[:, 1] - a, tri[:, 2] - a
    d11, d12, d22 = dot3(e1, e1), dot3(e1, e2), dot3(e2, e2)
    den = d11 * d22 - d12 * d12
    return a, e1, e2, d11, d12, d22, np.where(np.abs(den) > 1e-30, den, np.inf)


def _affine_uv(target: np.ndarray, tri: np.ndarray | tuple, tri_uv: np.ndarray) -> np.ndarray:
    """UVs (k, 2) of points (k, 3) through the affine map of triangles (k, 3, 3) (or their
    :func:`_affine_frames`) with UVs (k, 3, 2) (barycentrics of the point's projection on the
    triangle's plane, not clamped)."""
    a, e1, e2, d11, d12, d22, den = tri if isinstance(tri, tuple) else _affine_frames(tri)
    d = target - a
    p1, p2 = dot3(d, e1), dot3(d, e2)
    l1 = (d22 * p1 - d12 * p2) / den
    l2 = (d11 * p2 - d12 * p1) / den
    lam = np.stack([1 - l1 - l2, l1, l2], axis=1)
    return np.einsum("ij,ijk->ik", lam, tri_uv)


def affine_corner_uvs_arrays(mapped: np.ndarray, faces: np.ndarray, vertices: np.ndarray, template_faces: np.ndarray, corner_uv: np.ndarray, near: np.ndarray) -> np.ndarray:
    """(k, 3, 2) corner UVs of a part's faces ``faces (k, 3)`` over its mapped vertices ``mapped (j,
    3)``: each corner through the affine map of its face's template triangle ``near (k,)`` (a face of
    ``template_faces`` over ``vertices``, with UVs ``corner_uv``), clipped to [0, 1]. The array form
    of :func:`affine_corner_uvs` (compiled, the same operations in the same order)."""
    tri = vertices[template_faces[near]]
    tri_uv = corner_uv[near]
    out = np.empty((len(faces), 3, 2))
    frames = _affine_frames(tri)
    for k in range(3):
        out[:, k] = _affine_uv(mapped[faces[:, k]], frames, tri_uv)
    return np.clip(out, 0.0, 1.0)


def affine_corner_uvs(mapped: np.ndarray, faces: np.ndarray, vertices: np.ndarray, template_faces: np.ndarray, corner_uv: np.ndarray, near: np.ndarray) -> np.ndarray:
    """:func:`affine_corner_uvs_arrays` by the compiled kernel of :mod:`proctex.transfer.uv_kernels`
    (one pass over the faces), or in arrays where numba does not import."""
    try:
        from proctex.transfer.uv_kernels import affine_corner_uvs as compiled
    except ImportError:
        return affine_corner_uvs_arrays(mapped, faces, vertices, template_faces, corner_uv, near)
    return compiled(mapped, faces, vertices, template_faces, corner_uv, near)


def template_charts(assets: TemplateAssets) -> list[np.ndarray] | None:
    """Per group :func:`chart_labels` of the template's painted masks (computed once, kept on the
    assets); None when the assets carry no painted masks."""
    if assets.painted is None:
        return None
    if "charts" not in assets.derived:
        assets.derived["charts"] = [chart_labels(m) for m in assets.painted]
    return assets.derived["charts"]


#: Template faces checked first per shape face at run time (the nearest proxies of its mapped
#: centroid; the nearest one facing the face's own way wins, the search widening when none does).
UV_CANDIDATES = 4


#: ... and at most this many when none faces it (a thin wall's other side is among the nearest; a
#: face mapped far from any facing face keeps its plain nearest one instead of a wide search).
UV_MAX_CANDIDATES = 16


@dataclass(frozen=True)
class ChartLookup:
    """What the run-time coverage check (:func:`_inside_chart`) reads of one group texture.

    ``labels (H, W)``: :func:`chart_labels`. ``block_label (H*W,)``: per texel, the chart all four
    texels of its bilinear 2x2 block share, -1 where they differ (so one read answers for a whole
    bilinear lookup, :func:`proctex.texture.uv.bilinear_blocks`). ``block_room (H*W,)``: per texel ``T``,
    the largest ``r`` such that the texels at offsets ``-r .. r + 1`` (rows and columns) from ``T``
    all lie in its chart: every point within ``r`` texels (in each coordinate) of a lookup whose
    first texel is ``T`` reads only that chart (0 when ``T``'s own block leaves it).
    ``block_count (H + 1, W + 1) int32``: the summed-area table of the texels whose block lies in one
    painted chart (``block_label > 0``): how many such blocks a box of first texels holds, in four reads.
    """

    labels: np.ndarray
    block_label: np.ndarray
    block_room: np.ndarray
    block_count: np.ndarray | None = None


@dataclass(frozen=True)
class FaceRooms:
    """What the run time's first, cheap coverage test (:func:`_inside_rooms`) reads of one
    template group, per template face (computed once per family version, :func:`face_rooms`).

    ``chart (F,) int32``: the chart of the face's texture triangle (read at its centre, as
    :func:`part_uvs` always read it). ``box (F, 4) float64``: the triangle's bounding box in
    continuous texel coordinates (row min, row max, column min, column max; :func:`texel_coords`).
    ``room (F,) int64``: the least :attr:`ChartLookup.block_room` over the first texels of every
    bilinear lookup inside that box, or -1 when one of them reads beyond ``chart`` (or ``chart`` is
    0, unpainted).
    """

    chart: np.ndarray
    box: np.ndarray
    room: np.ndarray


def chart_lookup(labels: np.ndarray) -> ChartLookup:
    """:class:`ChartLookup` of chart ``labels (H, W)`` (:func:`chart_labels`)."""
    from scipy import ndimage

    from proctex.texture.uv import bilinear_blocks

    labels = np.asarray(labels, dtype=np.int32)
    # Chessboard distance of each texel to the nearest texel outside its chart (unpainted, so also
    # to any other chart); a block [-r, r + 1]^2 around T lies in the chart when the least of it
    # over T's 2x2 block is at least r + 1.
    cheb = ndimage.distance_transform_cdt(labels > 0, metric="chessboard").astype(np.int32)
    room = np.maximum(bilinear_blocks(cheb, "min") - 1, 0)
    same = bilinear_blocks(labels, "same")
    count = np.zeros((labels.shape[0] + 1, labels.shape[1] + 1), dtype=np.int32)
    count[1:, 1:] = (same > 0).astype(np.int32).cumsum(axis=0).cumsum(axis=1)
    return ChartLookup(labels, same.ravel(), room.ravel(), count)


def _texel_box(corner_uv: np.ndarray, height: int, width: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(box (k, 4), lo (k, 2), hi (k, 2))`` of triangles with UVs ``corner_uv (k, 3, 2)``: the
    bounding box in continuous texel coordinates (row min, row max, column min, column max;
    :func:`proctex.texture.uv.texel_coords`), and the first and last of the first texels
    (row, column; int64, clamped as :func:`proctex.texture.uv.bilinear_corner` clamps) of the
    bilinear lookups inside it."""
    from proctex.texture.uv import texel_coords

    k = len(corner_uv)
    r, c = (x.reshape(k, 3) for x in texel_coords(np.asarray(corner_uv, dtype=np.float64).reshape(-1, 2), height, width))
    box = np.stack([r.min(axis=1), r.max(axis=1), c.min(axis=1), c.max(axis=1)], axis=1)
    top = [height - 1, width - 1]
    return box, np.clip(np.floor(box[:, [0, 2]]), 0, top).astype(np.int64), np.clip(np.floor(box[:, [1, 3]]), 0, top).astype(np.int64)


def _triangle_chart(look: ChartLookup, tri_uv: np.ndarray) -> np.ndarray:
    """(k,) int32: the chart a texture triangle ``tri_uv (k, 3, 2)`` belongs to, read at its centre
    (the largest label its bilinear lookup there reads)."""
    from proctex.texture.uv import bilinear_texels

    h, w = look.labels.shape
    if not len(tri_uv):
        return np.zeros(0, np.int32)
    return look.labels.ravel()[bilinear_texels(np.asarray(tri_uv).mean(axis=1), h, w)].max(axis=1).astype(np.int32)


def _inside_box(corner_uv: np.ndarray, look: ChartLookup, chart: np.ndarray) -> np.ndarray:
    """(k,) bool: faces with UVs ``corner_uv (k, 3, 2)`` whose whole UV bounding box reads only chart
    ``chart (k,)``: every 2x2 block whose first texel lies in the box (the first texel of any
    lookup inside the face does) is one painted chart, by :attr:`ChartLookup.block_count`, and the
    first of them is ``chart``'s. Blocks of neighbouring first texels share two texels, so uniform
    blocks over the (connected) box are all one chart. Sound and exact for the box; a face whose box
    reaches beyond its chart (a long diagonal face along the rim) is for the probes."""
    h, w = look.labels.shape
    _, lo, hi = _texel_box(corner_uv, h, w)
    (i0, j0), (i1, j1) = lo.T, (hi + 1).T
    sat = look.block_count
    count = sat[i1, j1] - sat[i0, j1] - sat[i1, j0] + sat[i0, j0]
    return (count == (i1 - i0) * (j1 - j0)) & (look.block_label[i0 * w + j0] == np.asarray(chart))


def chart_lookups(assets: TemplateAssets) -> list[ChartLookup] | None:
    """Per group :func:`chart_lookup` of the template's charts, computed once and kept on the
    assets; None without painted masks."""
    charts = template_charts(assets)
    if charts is None:
        return None
    if "lookups" not in assets.derived:
        assets.derived["lookups"] = [chart_lookup(c) for c in charts]
    return assets.derived["lookups"]


def group_rooms(assets: TemplateAssets) -> list[FaceRooms] | None:
    """Per group :func:`face_rooms` of the template's faces over :func:`chart_lookups`, computed
    once and kept on the assets (a new family version is new assets); None without painted masks."""
    lookups = chart_lookups(assets)
    if lookups is None:
        return None
    if "rooms" not in assets.derived:
        assets.derived["rooms"] = [face_rooms(look, g.corner_uv) for look, g in zip(lookups, assets.groups)]
    return assets.derived["rooms"]


def face_rooms(look: ChartLookup, corner_uv: np.ndarray, window: int = 8) -> FaceRooms:
    """:class:`FaceRooms` of a template group's faces with UVs ``corner_uv (F, 3, 2)`` over its
    chart ``look``. Boxes spanning at most ``window`` texels a side are reduced together; larger
    ones one by one."""
    uv = np.asarray(corner_uv, dtype=np.float64)
    if uv.ndim != 3 or uv.shape[1:] != (3, 2):
        raise ValueError(f"corner_uv must be (F, 3, 2), got {uv.shape}")
    h, w = look.labels.shape
    n = len(uv)
    chart = _triangle_chart(look, uv)
    box, lo, hi = _texel_box(uv, h, w)
    # per texel: its room where its block is one chart, else -1 (compared with each face's chart below)
    label = look.block_label.reshape(h, w)
    room = np.where(label >= 0, look.block_room.reshape(h, w), -1).astype(np.int64)
    out = np.full(n, -1, dtype=np.int64)
    span = hi - lo + 1
    small = np.flatnonzero((span <= window).all(axis=1))
    if len(small):
        k = np.arange(window)
        rows = lo[small, 0, None] + k  # (s, window)
        cols = lo[small, 1, None] + k
        valid = (k < span[small, 0, None])[:, :, None] & (k < span[small, 1, None])[:, None, :]
        ri, ci = np.minimum(rows, h - 1)[:, :, None], np.minimum(cols, w - 1)[:, None, :]
        same = (label[ri, ci] == chart[small, None, None]) | ~valid
        least = np.where(valid, room[ri, ci], np.iinfo(np.int64).max).min(axis=(1, 2))
        out[small] = np.where(same.all(axis=(1, 2)), least, -1)
    for f in np.flatnonzero(~(span <= window).all(axis=1)):
        block = np.s_[lo[f, 0] : hi[f, 0] + 1, lo[f, 1] : hi[f, 1] + 1]
        out[f] = room[block].min() if (label[block] == chart[f]).all() else -1
    out[chart <= 0] = -1  # a triangle centred on unpainted texels proves nothing
    return FaceRooms(chart, box, out)


def _inside_rooms(corner_uv: np.ndarray, rooms: FaceRooms, near: np.ndarray, height: int, width: int) -> np.ndarray:
    """(k,) bool: faces with UVs ``corner_uv (k, 3, 2)`` mapped through template faces ``near
    (k,)`` proven to read only their template face's chart, by one test per face: each corner
    within ``d`` texels (in each coordinate) of the template face's box, and ``ceil(d)`` at most
    its :attr:`FaceRooms.room`. Sound: every point of the face lies within ``d`` of a point ``q`` of
    the box (the box grown by ``d`` is convex), so its lookup's first texel is within ``ceil(d)`` of
    ``q``'s, whose block grown by its room lies in the chart. Faces it does not prove are for
    :func:`_inside_chart`."""
    try:
        from proctex.transfer.uv_kernels import inside_rooms
    except ImportError:
        return _inside_rooms_arrays(corner_uv, rooms, near, height, width)
    return inside_rooms(corner_uv, rooms.box, rooms.room, near, height, width)


def _inside_rooms_arrays(corner_uv: np.ndarray, rooms: FaceRooms, near: np.ndarray, height: int, width: int) -> np.ndarray:
    """:func:`_inside_rooms` in array operations (the compiled kernel's reference and fallback)."""
    from proctex.texture.uv import texel_coords

    k = len(corner_uv)
    r, c = (x.reshape(k, 3) for x in texel_coords(np.asarray(corner_uv).reshape(-1, 2), height, width))
    box = rooms.box[near]
    d = np.maximum(np.maximum(box[:, 0:1] - r, r - box[:, 1:2]), np.maximum(box[:, 2:3] - c, c - box[:, 3:4])).max(axis=1)
    return np.ceil(np.maximum(d, 0.0)) <= rooms.room[near]


def part_uvs(
    assets: GroupAssets, mapped: np.ndarray, faces: np.ndarray, charts: np.ndarray | ChartLookup | None = None, normals: np.ndarray | None = None, rooms: FaceRooms | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Corner UVs (k, 3, 2) of a part's faces from its mapped vertices (j, 3) (template normalised frame).

    Each face takes the template face nearest to its mapped centroid among those facing its way
    (:meth:`SurfaceIndex.query_facing`: a thin wall's inside never reads its outside; ``normals
    (k, 3)``: the faces' normals in the representative's frame, default those of the mapped
    triangles) and that face's affine UV map.
    With ``charts`` (the group texture's :func:`chart_labels`, or their :func:`chart_lookup`, which
    the run time keeps per template), a face whose affine UVs would leave the chart of its template
    triangle anywhere (a large face extrapolated beyond it reading unpainted texels or another
    chart; :func:`_inside_chart` proves every face inside) instead takes, per corner, the
    closest point of that template triangle: its UVs then stay in the chart (squeezed, but
    coloured). A face still reading outside the chart takes the colour at the template triangle's
    centre (all three corners there), so real-time coverage has no unpainted pixel. ``rooms`` (the
    group's :func:`face_rooms`, which the run time keeps per template): most faces are proven
    inside by one test each (:func:`_inside_rooms`), the rest by :func:`_inside_chart`.

    Returns (corner_uv, template face per face (k,)).
    """
    centroid = face_centroids(mapped, faces)
    # The template face on the face's own side: a thin wall's inside never reads its outside. The
    # side comes from the part's own faces in the representative's frame (``normals``), which a
    # mapper's small errors cannot fold over; else from the mapped triangles.
    normal = np.asarray(normals, dtype=np.float64) if normals is not None else side_normals(mapped, faces)
    near = assets.index.facing_faces(centroid, normal, k=UV_CANDIDATES, max_k=UV_MAX_CANDIDATES)
    out = affine_corner_uvs(mapped, faces, assets.vertices, assets.faces, assets.corner_uv, near)
    if charts is not None and len(faces):
        look = charts if isinstance(charts, ChartLookup) else chart_lookup(charts)
        h, w = look.labels.shape
        if rooms is not None:  # most faces are proven by one test against their template face's room
            target = rooms.chart[near]
            bad = ~_inside_rooms(out, rooms, near, h, w)
            rest = np.flatnonzero(bad)
            bad[rest] = ~_inside_chart(out[rest], look, target[rest])
        else:
            target = _triangle_chart(look, assets.corner_uv[near])  # the template triangle's chart
            bad = ~_inside_chart(out, look, target)
        if bad.any():
            from proctex.geometry.surface import closest_point_on_triangles

            fi = np.flatnonzero(bad)
            t = assets.vertices[assets.faces[near[fi]]]
            t_uv = assets.corner_uv[near[fi]]
            for k in range(3):
                _, bary = closest_point_on_triangles(mapped[faces[fi, k]], t[:, 0], t[:, 1], t[:, 2])
                out[fi, k] = np.einsum("ij,ijk->ik", bary, t_uv)
            # Still reading outside the chart somewhere (a probe on unpainted texels: a sliver
            # template triangle on the chart's rim): the face takes the colour at its template
            # triangle's centre, so no visible pixel is unpainted.
            still = ~_inside_chart(out[fi], look, target[fi])
            out[fi[still]] = t_uv[still].mean(axis=1)[:, None]
    return out, near


def side_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(k, 3) area-weighted normals of a part's faces (``vertices (j, 3)`` in the representative's
    frame): which side of a thin wall each face is on (:func:`part_uvs`); the faces'
    :func:`proctex.texture.pbr.area_normals` (compiled where numba imports)."""
    return area_normals(vertices, faces)


def face_centroids(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(k, 3) centroids of ``faces (k, 3)`` over ``points (j, 3)``: compiled
    (:func:`proctex.transfer.uv_kernels.face_centroids`), or ``points[faces].mean(axis=1)`` (the
    same bits) where numba does not import."""
    try:
        from proctex.transfer.uv_kernels import face_centroids as compiled
    except ImportError:
        return np.asarray(points, dtype=np.float64)[faces].mean(axis=1)
    return compiled(points, faces)


@lru_cache(maxsize=64)
def _bary_grid(n: int) -> np.ndarray:
    """((n + 1)(n + 2) / 2, 3) barycentric points of a triangle split ``n`` times per edge
    (corners and edge points included)."""
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    keep = i + j <= n
    i, j = i[keep], j[keep]
    grid = np.stack([n - i - j, i, j], axis=1) / n
    grid.flags.writeable = False  # cached: shared by every call
    return grid


def _subdivide(tri: np.ndarray) -> np.ndarray:
    """(4n, 3, 2) midpoint subdivision of triangles ``tri (n, 3, 2)``: child ``4i + c`` of triangle ``i``."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, bc, ca = (a + b) / 2, (b + c) / 2, (c + a) / 2
    out = np.empty((len(tri), 4, 3, tri.shape[2]))
    for child, corners in enumerate(((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))):
        for k, corner in enumerate(corners):
            out[:, child, k] = corner
    return out.reshape(-1, 3, tri.shape[2])


def _inside_chart(corner_uv: np.ndarray, charts: np.ndarray | ChartLookup, chart: np.ndarray, leaf: float = 2.0, max_level: int = 12) -> np.ndarray:
    """(k,) bool: faces with UVs ``corner_uv (k, 3, 2)`` that read (bilinearly) only texels of
    chart ``chart (k,)`` of ``charts`` (:func:`chart_labels` (H, W), or their :func:`chart_lookup`)
    anywhere on the face. Sound: a face reported inside is inside; one within a texel or two of its
    chart's rim may be reported outside though every read is inside.

    A face whose whole UV box reads only its chart passes at once (:func:`_inside_box`; the
    lookups built by :func:`chart_lookup` carry the count it reads). Every point of a triangle lies
    within half its longest edge ``e`` of one of its corners, edge midpoints and centre. So a
    (sub-)triangle passes when each of those 7 probes reads its chart
    with room ``ceil(e / 2)`` around it (:attr:`ChartLookup.block_room`), fails when a probe reads
    another chart or an unpainted texel, and is otherwise split in four, down to triangles no
    longer than ``leaf`` (<= 2) texels, which fail (within a texel of the rim: not proven). The
    work grows with the length of rim a face runs along, not with its area; a face not settled
    after ``max_level`` splits is reported outside. Compiled where numba imports
    (:func:`proctex.transfer.uv_kernels.inside_chart`, the same answers as
    :func:`_inside_chart_arrays`)."""
    if not 0 < leaf <= 2.0:
        raise ValueError(f"leaf must be in (0, 2] texels, got {leaf}")
    if isinstance(max_level, bool) or not isinstance(max_level, (int, np.integer)) or not 0 <= max_level <= 64:
        raise ValueError(f"max_level must be an integer in [0, 64], got {max_level!r}")
    look = charts if isinstance(charts, ChartLookup) else chart_lookup(charts)
    h, w = look.labels.shape
    grid = _probe_grid()
    try:
        from proctex.transfer.uv_kernels import inside_chart
    except ImportError:
        return _inside_chart_arrays(corner_uv, look, chart, grid, leaf, max_level)
    return inside_chart(corner_uv, chart, look.block_label, look.block_room, look.block_count, grid, h, w, leaf, max_level)


@lru_cache(maxsize=1)
def _probe_grid() -> np.ndarray:
    """(7, 3) barycentric probes of :func:`_inside_chart`: the corners, the edge midpoints, the centre."""
    grid = np.vstack([_bary_grid(2), np.full((1, 3), 1.0 / 3.0)])
    grid.flags.writeable = False
    return grid


def _inside_chart_arrays(corner_uv: np.ndarray, look: ChartLookup, chart: np.ndarray, grid: np.ndarray, leaf: float, max_level: int) -> np.ndarray:
    """:func:`_inside_chart` in array operations, level by level over all open sub-triangles (the
    compiled kernel's reference and fallback: the same probes, summed in the same order)."""
    from proctex.texture.uv import bilinear_corner

    h, w = look.labels.shape
    k = len(corner_uv)
    ok = np.ones(k, dtype=bool)
    tri, owner = np.asarray(corner_uv, dtype=np.float64), np.arange(k)
    if look.block_count is not None and k:  # most faces: their whole box at once
        boxed = _inside_box(tri, look, np.asarray(chart))
        tri, owner = tri[~boxed], owner[~boxed]
    d = (tri - tri[:, [1, 2, 0]]) * np.array([w, h])
    edge = np.sqrt((d[:, :, 0] * d[:, :, 0] + d[:, :, 1] * d[:, :, 1]).max(axis=1))  # texels; halved by every split
    for _ in range(int(max_level) + 1):
        if not len(tri):
            break
        probes = (grid[None, :, 0, None] * tri[:, None, 0] + grid[None, :, 1, None] * tri[:, None, 1]) + grid[None, :, 2, None] * tri[
            :, None, 2
        ]  # (n, 7, 2), not a matrix product (whose sums a BLAS may fuse)
        idx = bilinear_corner(probes.reshape(-1, 2), h, w).reshape(len(tri), -1)  # (n, 7)
        inside = (look.block_label[idx] == np.asarray(chart)[owner][:, None]).all(axis=1)
        ok[owner[~inside]] = False
        settled = look.block_room[idx].min(axis=1) >= np.ceil(edge / 2)
        open_ = inside & ~settled & ok[owner]
        ok[owner[open_ & (edge <= leaf)]] = False  # at the rim: not proven
        split = open_ & (edge > leaf)
        tri, owner, edge = _subdivide(tri[split]), np.repeat(owner[split], 4), np.repeat(edge[split] / 2, 4)
    ok[owner] = False  # not settled within max_level splits
    return ok
