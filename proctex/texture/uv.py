"""UV atlases per part group, texel <-> surface maps and seam padding (docs/texturing.md).

Conventions used everywhere in ProcTex:

- UVs follow OpenGL/OBJ: ``u`` to the right, ``v`` up, ``(0, 0)`` the bottom-left of the image.
- Images are stored row 0 at the top, so texel ``(i, j)`` of an ``H x W`` texture has its centre at
  ``u = (j + 0.5) / W``, ``v = 1 - (i + 0.5) / H``.
- UVs are per face corner (``corner_uv (m, 3, 2)``): seams need no vertex splitting in our arrays.

Each group's *representative* part is unwrapped once with xatlas; the other members reuse that atlas
through their member map (``x_rep = R x_member + t``). Parts xatlas cannot unwrap (zero-area
triangles make it return NaN) fall back to a planar projection, so UVs are always finite.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from proctex.geometry.parts import Grouping, MemberMap, PartInfo
from proctex.geometry.raster import rasterise
from proctex.geometry.shape import Shape
from proctex.geometry.surface import SurfaceIndex, face_normals, normalised_frame, triangle_areas

AREA_EPS = 1e-12  # zero area, relative to the part's normalised frame


# ------------------------------------------------------------------------------------------ atlas
@dataclass
class Atlas:
    """The UV layout of one part (a group's representative).

    Attributes:
        corner_uv: (k, 3, 2) float64 UVs in [0, 1] per face corner, faces in the part's order.
        method: "xatlas" or "planar" (fallback for parts xatlas cannot unwrap).
        charts: number of charts.
        resolution: the texture size the packing was made for (padding is in its texels).
        padding: texels between charts at that resolution.
        seconds: time spent unwrapping.
        notes: anything worth telling a user (fallbacks, NaN repaired).
    """

    corner_uv: np.ndarray
    method: str
    charts: int
    resolution: int
    padding: int
    seconds: float
    notes: list[str] = field(default_factory=list)


def _check_mesh(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"vertices must be (n, 3), got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"faces must be (m, 3), got {f.shape}")
    if len(f) == 0:
        raise ValueError("mesh has no faces")
    if f.min() < 0 or f.max() >= len(v):
        raise ValueError(f"face indices must be in [0, {len(v)})")
    if not np.isfinite(v).all():
        raise ValueError("vertices contain NaN or inf")
    return v, f


def planar_uv(vertices: np.ndarray, faces: np.ndarray, margin: float = 0.05) -> np.ndarray:
    """(k, 3, 2) corner UVs from projecting onto the two main axes (PCA), fitted into [margin, 1-margin]².

    Works for any input, including zero-area and single-point parts (all UVs then sit at the centre).
    """
    v, f = _check_mesh(vertices, faces)
    used = np.unique(f)
    p = v[used] - v[used].mean(axis=0)
    if len(p) > 1 and np.abs(p).max() > 0:
        _, _, vt = np.linalg.svd(p, full_matrices=False)
        axes = vt[:2] if len(vt) >= 2 else np.vstack([vt, np.zeros(3)])
    else:
        axes = np.eye(3)[:2]
    q = (v - v[used].mean(axis=0)) @ axes.T
    lo, hi = q[used].min(axis=0), q[used].max(axis=0)
    span = float((hi - lo).max())
    if span <= 0:
        q = np.full_like(q, 0.5)
    else:
        q = (q - (lo + hi) / 2) / span * (1 - 2 * margin) + 0.5
    return q[f]


# xatlas's default (multi-threaded) build can hang for ever when an Atlas is destroyed: its task
# scheduler's destructor wakes each worker thread with notify_one without holding the worker's mutex,
# so a worker that has just found its wake-up flag unset and not yet gone to sleep misses the wake-up
# and join() never returns. CI saw it under load: a bake stuck 16 minutes in the Atlas's destructor
# (the innermost Python frame the caller of unwrap, whose locals were being freed). `make setup`
# builds xatlas with XA_MULTITHREADED=0: it starts no thread, so there is nothing to miss (and the
# binding holds the GIL throughout generate, so its threads never ran beside Python's anyway). With a
# threaded xatlas (the PyPI wheel), :func:`_release` lets an Atlas go only once each of its workers
# sleeps, as the kernel reports it, and keeps an Atlas whose workers never settle (idle threads) rather
# than risk the hang.
XATLAS_SETTLE_S = 2.0
_KEPT: list = []  # threaded xatlas Atlases whose workers never settled (see above)


def _tasks() -> set[str]:
    """This process's thread ids (Linux ``/proc/self/task``; empty elsewhere)."""
    try:
        return set(os.listdir("/proc/self/task"))
    except OSError:
        return set()


def _sleeping(tid: str) -> bool:
    """Whether thread ``tid`` of this process sleeps (state S: xatlas's workers sleep only in their
    condition variable's wait) or is gone."""
    try:
        with open(f"/proc/self/task/{tid}/stat", "rb") as fh:
            return fh.read().rsplit(b") ", 1)[1][:1] == b"S"
    except (OSError, IndexError):
        return True


def _release(holder: list, workers: set[str], settle_s: float = XATLAS_SETTLE_S) -> bool:
    """Destroy the xatlas Atlas in ``holder`` (a one-item list: the caller keeps no other reference),
    once each thread of ``workers`` (the ids it started) was seen asleep twice in a row; after
    ``settle_s`` s the Atlas is kept instead (:data:`_KEPT`). True when it was destroyed."""
    if workers:
        deadline, settled = time.monotonic() + settle_s, 0
        while settled < 2:
            settled = settled + 1 if all(_sleeping(t) for t in workers) else 0
            if settled < 2 and time.monotonic() > deadline:
                _KEPT.append(holder.pop())
                return False
            time.sleep(0.0002)
    holder.clear()
    return True


def xatlas_threads() -> int:
    """How many threads an xatlas Atlas starts here: 0 for the single-threaded build ``make setup``
    makes, -1 where the platform cannot tell (no ``/proc``)."""
    import xatlas

    if not _tasks():
        return -1
    before = _tasks()
    holder = [xatlas.Atlas()]
    started = _tasks() - before
    _release(holder, started)
    return len(started)


def _xatlas_run(v32: np.ndarray, f32: np.ndarray, resolution: int | None, padding: int) -> tuple[np.ndarray, np.ndarray, int, int]:
    """One xatlas unwrap of ``v32 (n, 3) float32``, ``f32 (k, 3) uint32``, packed for ``resolution``
    (None: xatlas picks it, one page): ``(indices (k, 3) int64 into uvs, uvs (m, 2) float64, pages,
    charts)``. The Atlas is destroyed by :func:`_release` whatever happens."""
    import xatlas

    before = _tasks()
    holder = [xatlas.Atlas()]
    workers = _tasks() - before
    try:
        holder[0].add_mesh(v32, f32)
        pack = xatlas.PackOptions()
        if resolution is not None:
            pack.resolution = int(resolution)
        pack.padding = int(padding)
        pack.bilinear = True
        holder[0].generate(xatlas.ChartOptions(), pack)
        pages, charts = int(holder[0].atlas_count), int(holder[0].chart_count)
        _, indices, uvs = holder[0][0]  # copies (the binding fills new arrays)
        return np.asarray(indices, dtype=np.int64), np.asarray(uvs, dtype=np.float64), pages, charts
    finally:
        _release(holder, workers)


def unwrap(vertices: np.ndarray, faces: np.ndarray, resolution: int = 1024, padding: int = 4) -> Atlas:
    """UV atlas of one part with xatlas (planar fallback when xatlas fails or returns NaN).

    Args:
        vertices: (n, 3) float64; faces: (k, 3) int64 (at least one face).
        resolution: texture size the charts are packed for; padding: texels kept between charts.
        (xatlas is deterministic: no seed.)

    Returns:
        :class:`Atlas` with finite ``corner_uv`` in [0, 1].
    """
    v, f = _check_mesh(vertices, faces)
    if resolution < 8 or padding < 0:
        raise ValueError(f"resolution must be >= 8 and padding >= 0, got {resolution}, {padding}")
    t0 = time.perf_counter()
    notes: list[str] = []
    # xatlas works in float32 with absolute epsilons: unwrap in the part's normalised frame
    # (UVs do not depend on scale), so 0.15-unit and 300-unit parts unwrap alike.
    used = np.unique(f)
    center, radius = normalised_frame(v[used])
    v = (v - center) / (radius if radius > 0 else 1.0)
    good = triangle_areas(v, f) > AREA_EPS
    if not good.any():
        uv = planar_uv(v, f)
        return Atlas(uv, "planar", 1, resolution, padding, time.perf_counter() - t0, ["all triangles have zero area: planar UVs"])
    corner = np.empty((len(f), 3, 2))
    try:
        v32, f32 = v.astype(np.float32), f[good].astype(np.uint32)
        indices, uvs, pages, charts = _xatlas_run(v32, f32, resolution, padding)
        if pages != 1:
            # Did not fit one page at that density: repack without a fixed resolution (one page).
            notes.append(f"xatlas made {pages} pages at {resolution}: repacked into one")
            indices, uvs, pages, charts = _xatlas_run(v32, f32, None, padding)
        uv_good = uvs[indices]
        if not np.isfinite(uv_good).all():
            raise ValueError("xatlas returned non-finite UVs")
        corner[good] = uv_good
        method = "xatlas"
    except Exception as exc:  # xatlas raises plain RuntimeErrors on odd input
        notes.append(f"xatlas failed ({exc}): planar UVs")
        return Atlas(planar_uv(v, f), "planar", 1, resolution, padding, time.perf_counter() - t0, notes)
    if not good.all():
        # Zero-area faces are invisible; park their corners on the UV of a neighbouring good corner.
        bad = np.flatnonzero(~good)
        vertex_uv = np.full((len(v), 2), np.nan)
        vertex_uv[f[good].ravel()] = corner[good].reshape(-1, 2)
        fallback = corner[good][0, 0]
        uv_bad = vertex_uv[f[bad]]
        uv_bad[~np.isfinite(uv_bad)] = np.broadcast_to(fallback, uv_bad.shape)[~np.isfinite(uv_bad)]
        corner[bad] = uv_bad
        notes.append(f"{len(bad)} zero-area faces kept out of the unwrap")
    np.clip(corner, 0.0, 1.0, out=corner)
    return Atlas(corner, method, charts, resolution, padding, time.perf_counter() - t0, notes)


# ------------------------------------------------------------------------------- member transfer
def _local_faces(shape: Shape, part: PartInfo) -> np.ndarray:
    lookup = np.full(shape.n_vertices, -1, dtype=np.int64)
    lookup[part.vertices] = np.arange(len(part.vertices))
    return lookup[shape.faces[part.faces]]


def member_corner_uv(shape: Shape, rep: PartInfo, rep_uv: np.ndarray, member: PartInfo, mmap: MemberMap) -> np.ndarray:
    """(k, 3, 2) corner UVs for a group member, read off its representative's atlas.

    Members matched vertex-for-vertex with the same triangulation copy the UVs exactly. Otherwise each
    member triangle is mapped onto the representative (``x_rep = R x + t``; a "deformed" member's
    vertex i onto the representative's vertex i), the representative face
    nearest to its centroid is found, and the triangle's corners get UVs by that face's affine map
    (barycentrics of the corners projected on the face's plane), so a triangle never spans two charts.
    """
    if member.index == rep.index:
        return rep_uv.copy()
    if mmap.method in ("topology", "similar", "deformed") and member.n_faces == rep.n_faces:
        if np.array_equal(_local_faces(shape, member), _local_faces(shape, rep)):
            return rep_uv.copy()
    rep_tri = shape.vertices[shape.faces[rep.faces]]  # (kr, 3, 3)
    if mmap.method == "deformed":  # its vertex i is the representative's vertex i: its faces laid on the representative's vertices
        mem_tri = shape.vertices[rep.vertices][np.searchsorted(member.vertices, shape.faces[member.faces])]
    else:
        mem_tri = shape.vertices[shape.faces[member.faces]] @ mmap.R.T + mmap.t  # (k, 3, 3)
    index = SurfaceIndex(shape.vertices, shape.faces[rep.faces])
    near = index.query(mem_tri.mean(axis=1), exact=True).faces
    a, b, c = rep_tri[near, 0], rep_tri[near, 1], rep_tri[near, 2]
    e1, e2 = b - a, c - a
    d11, d12, d22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    den = d11 * d22 - d12 * d12
    den = np.where(np.abs(den) > 1e-30, den, np.inf)  # degenerate target: all corners at its first corner
    out = np.empty((member.n_faces, 3, 2))
    for k in range(3):
        d = mem_tri[:, k] - a
        p1, p2 = (d * e1).sum(1), (d * e2).sum(1)
        l1 = (d22 * p1 - d12 * p2) / den
        l2 = (d11 * p2 - d12 * p1) / den
        lam = np.stack([1 - l1 - l2, l1, l2], axis=1)
        out[:, k] = np.einsum("ij,ijk->ik", lam, rep_uv[near])
    return np.clip(out, 0.0, 1.0)


# ------------------------------------------------------------------------------------- shape UVs
@dataclass
class ShapeUV:
    """UVs of a whole shape: every face reads one group's texture.

    Attributes:
        corner_uv: (m, 3, 2) float64 per face corner.
        face_group: (m,) int64 group id per face (-1: no texture).
        atlases: one :class:`Atlas` per group (of its representative).
        resolution: the texture size the atlases were packed for.
    """

    corner_uv: np.ndarray
    face_group: np.ndarray
    atlases: list[Atlas]
    resolution: int

    @property
    def n_groups(self) -> int:
        return len(self.atlases)


def shape_uv(shape: Shape, grouping: Grouping, resolution: int = 1024, padding: int = 4) -> ShapeUV:
    """Unwrap each group's representative and give every member its UVs (see :func:`member_corner_uv`)."""
    corner = np.zeros((shape.n_faces, 3, 2))
    face_group = np.full(shape.n_faces, -1, dtype=np.int64)
    atlases = []
    for g in grouping.groups:
        rep = grouping.parts[g.representative]
        atlas = unwrap(shape.vertices[rep.vertices], _local_faces(shape, rep), resolution=resolution, padding=padding)
        atlases.append(atlas)
        for member, mmap in zip(g.members, g.maps):
            part = grouping.parts[member]
            corner[part.faces] = member_corner_uv(shape, rep, atlas.corner_uv, part, mmap)
            face_group[part.faces] = g.index
    if not np.isfinite(corner).all():  # pragma: no cover - guarded above; keep the promise explicit
        raise RuntimeError("non-finite UVs")
    return ShapeUV(corner, face_group, atlases, resolution)


def fit_unit_square(uv: np.ndarray, margin: float = 0.02) -> tuple[np.ndarray, bool]:
    """UVs that already lie in [0, 1] as they are; others scaled uniformly (aspect kept) and moved
    into ``[margin, 1 - margin]``. Returns ``(uv, moved)``. ``ValueError`` for a layout with no extent."""
    uv = np.asarray(uv, dtype=np.float64)
    flat = uv.reshape(-1, 2)
    lo, hi = flat.min(axis=0), flat.max(axis=0)
    extent = float((hi - lo).max())
    if not np.isfinite(extent) or extent <= 1e-9:
        raise ValueError("the UV layout has no extent (every corner at one point)")
    if lo.min() >= 0.0 and hi.max() <= 1.0:
        return uv.copy(), False
    return (uv - lo) * ((1.0 - 2 * margin) / extent) + margin, True


def source_uv(shape: Shape, grouping: Grouping, corner_uv: np.ndarray, resolution: int = 1024) -> ShapeUV:
    """Keep UVs the source made (a Blender graph's UV map) instead of unwrapping: each group's
    representative keeps its own layout (moved into [0, 1] when it lies outside, see
    :func:`fit_unit_square`) and members read it off as in :func:`shape_uv`. A representative whose
    layout has no extent is unwrapped instead; both that and overlapping UVs (texels shared by
    several faces) are said in the atlas notes.

    Args:
        corner_uv: (m, 3, 2) float64 UVs per face corner of ``shape``.
    """
    corner_uv = np.asarray(corner_uv, dtype=np.float64)
    if corner_uv.shape != (shape.n_faces, 3, 2) or not np.isfinite(corner_uv).all():
        raise ValueError(f"corner_uv must be finite ({shape.n_faces}, 3, 2), got {corner_uv.shape}")
    corner = np.zeros((shape.n_faces, 3, 2))
    face_group = np.full(shape.n_faces, -1, dtype=np.int64)
    atlases = []
    for g in grouping.groups:
        rep = grouping.parts[g.representative]
        t0 = time.perf_counter()
        try:
            rep_uv, moved = fit_unit_square(corner_uv[rep.faces])
        except ValueError as exc:
            atlas = unwrap(shape.vertices[rep.vertices], _local_faces(shape, rep), resolution=resolution)
            atlas.notes.append(f"the source's UVs were not used for group {g.index}: {exc}; unwrapped instead")
        else:
            e1, e2 = rep_uv[:, 1] - rep_uv[:, 0], rep_uv[:, 2] - rep_uv[:, 0]
            area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum() * resolution**2  # in texels, overlaps counted twice
            covered = len(texel_map(shape.vertices, shape.faces[rep.faces], rep_uv, resolution).ij)
            shared = max(0.0, 1.0 - covered / area) if area > 64 else 0.0
            notes = [f"UVs moved into [0, 1] for group {g.index}"] if moved else []
            if shared > 0.01:
                notes.append(f"the source's UVs overlap for group {g.index}: {100 * shared:.1f}% of its texels serve several faces")
            atlas = Atlas(rep_uv, "source", 0, resolution, 0, time.perf_counter() - t0, notes)
        atlases.append(atlas)
        for member, mmap in zip(g.members, g.maps):
            part = grouping.parts[member]
            corner[part.faces] = member_corner_uv(shape, rep, atlas.corner_uv, part, mmap)
            face_group[part.faces] = g.index
    return ShapeUV(corner, face_group, atlases, resolution)


# -------------------------------------------------------------------------------------- texel maps
@dataclass
class TexelMap:
    """Which texels of an ``H x W`` texture a mesh covers, and where they lie on the surface.

    Covered texels are those whose centre lies in a UV triangle, plus, for every face no texel centre
    falls in (tiny faces), the texel under its UV centroid, so that every face owns at least one texel.

    Attributes:
        height, width: texture size.
        ij: (t, 2) int64 (row, column) of each covered texel.
        face: (t,) int64 index into the given faces.
        bary: (t, 3) float64 barycentrics (clamped into the triangle).
        points: (t, 3) float64 surface points; normals: (t, 3) float64 unit face normals.
    """

    height: int
    width: int
    ij: np.ndarray
    face: np.ndarray
    bary: np.ndarray
    points: np.ndarray
    normals: np.ndarray

    @property
    def mask(self) -> np.ndarray:
        """(H, W) bool covered texels."""
        m = np.zeros((self.height, self.width), dtype=bool)
        m[self.ij[:, 0], self.ij[:, 1]] = True
        return m

    @property
    def flat(self) -> np.ndarray:
        """(t,) int64 row-major texel indices."""
        return self.ij[:, 0] * self.width + self.ij[:, 1]


def uv_to_pixel(uv: np.ndarray, height: int, width: int) -> np.ndarray:
    """(..., 2) UVs -> (..., 2) continuous pixel coordinates (x = column, y = row; centres at +0.5)."""
    uv = np.asarray(uv, dtype=np.float64)
    return np.stack([uv[..., 0] * width, (1.0 - uv[..., 1]) * height], axis=-1)


def _check_texel_args(vertices, faces, corner_uv, height, width):
    v, f = _check_mesh(vertices, faces)
    uv = np.asarray(corner_uv, dtype=np.float64)
    if uv.shape != (len(f), 3, 2):
        raise ValueError(f"corner_uv must be ({len(f)}, 3, 2), got {uv.shape}")
    if not np.isfinite(uv).all():
        raise ValueError("corner_uv contains NaN or inf")
    if int(height) < 1 or int(width) < 1:
        raise ValueError(f"texture size must be positive, got {height}x{width}")
    return v, f, uv


def texel_map(vertices: np.ndarray, faces: np.ndarray, corner_uv: np.ndarray, height: int, width: int | None = None) -> TexelMap:
    """Texel <-> surface map of a mesh with per-corner UVs (vectorised rasterisation in UV space).

    Args:
        vertices: (n, 3) float64; faces: (k, 3) int64; corner_uv: (k, 3, 2) float64.
        height, width: texture size (width defaults to height).
    """
    width = height if width is None else width
    v, f, uv = _check_texel_args(vertices, faces, corner_uv, height, width)
    H, W = int(height), int(width)
    face_img, bary_img = rasterise(uv_to_pixel(uv, H, W), H, W)
    flat = np.flatnonzero(face_img.ravel() >= 0)
    ii, jj = np.divmod(flat, W)
    fid = face_img.ravel()[flat]
    bary = bary_img.reshape(-1, 3)[flat]
    # Faces without a texel of their own get the texel under their UV centroid (if still free).
    owned = np.zeros(len(f), dtype=bool)
    owned[fid] = True
    lonely = np.flatnonzero(~owned)
    if len(lonely):
        c = uv_to_pixel(uv[lonely].mean(axis=1), H, W)
        cj = np.clip(np.floor(c[:, 0]).astype(np.int64), 0, W - 1)
        ci = np.clip(np.floor(c[:, 1]).astype(np.int64), 0, H - 1)
        flat = ci * W + cj
        flat, first = np.unique(flat, return_index=True)
        free = face_img.ravel()[flat] < 0
        sel = first[free]
        ii = np.concatenate([ii, ci[sel]])
        jj = np.concatenate([jj, cj[sel]])
        fid = np.concatenate([fid, lonely[sel]])
        bary = np.concatenate([bary, np.full((len(sel), 3), 1.0 / 3.0)])
    np.clip(bary, 0.0, None, out=bary)
    bary /= bary.sum(axis=1, keepdims=True)
    tri = v[f]
    points = bary[:, :1] * tri[fid, 0] + bary[:, 1:2] * tri[fid, 1] + bary[:, 2:] * tri[fid, 2]
    normals = face_normals(v, f)[fid]
    ij = np.stack([ii, jj], axis=1)
    if len(lonely):
        order = np.lexsort((jj, ii))
        ij, fid, bary, points, normals = ij[order], fid[order], bary[order], points[order], normals[order]
    return TexelMap(H, W, ij, fid, bary, points, normals)


def texel_barycentric(ij: np.ndarray, corner_uv: np.ndarray, height: int, width: int) -> np.ndarray:
    """(t, 3) barycentrics of texel centres ``ij`` (t, 2) (row, column) in their faces' UV triangles
    ``corner_uv`` (t, 3, 2), not clamped (at least -1 each: a texel on a chart's border may lie past
    its face's edge, up to the face's size)."""
    from proctex.geometry.surface import plane_barycentric

    tri = uv_to_pixel(np.asarray(corner_uv, dtype=np.float64), height, width)
    centre = np.stack([ij[:, 1] + 0.5, ij[:, 0] + 0.5], axis=1)
    return plane_barycentric(centre, tri, floor=-1.0)


def ring_texels(texels: TexelMap, vertices: np.ndarray, faces: np.ndarray, corner_uv: np.ndarray, ring: int = 2) -> TexelMap:
    """The texels within ``ring`` texels of a chart that no chart covers, each placed on the surface
    extended past the chart's edge: the nearest covered texel's face, at the texel centre's
    barycentrics in that face's UV triangle (extrapolated; each at least -1, so a point lies at most
    a triangle's size beyond its edge). A painter that colours 3D points paints them as it would the
    surface there, so a bilinear read at a chart's border blends true colours instead of copies
    (:func:`pad_seams` still fills the rest of the gutter). Same fields as ``texels``; ``faces`` and
    ``corner_uv`` are those ``texels`` was made from."""
    mask = texels.mask
    if ring < 1 or not mask.any():
        return TexelMap(texels.height, texels.width, np.zeros((0, 2), np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)))
    H, W = texels.height, texels.width
    dist, (ri, rj) = ndimage.distance_transform_edt(~mask, return_indices=True)
    sel = (~mask) & (dist <= ring)
    ii, jj = np.nonzero(sel)
    owner = np.full((H, W), -1, dtype=np.int64)
    owner[texels.ij[:, 0], texels.ij[:, 1]] = texels.face
    fid = owner[ri[ii, jj], rj[ii, jj]]
    v, f = np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)
    bary = texel_barycentric(np.stack([ii, jj], axis=1), np.asarray(corner_uv, dtype=np.float64)[fid], H, W)
    tri = v[f[fid]]
    points = np.einsum("kc,kcd->kd", bary, tri)
    return TexelMap(H, W, np.stack([ii, jj], axis=1).astype(np.int64), fid, bary, points, face_normals(v, f)[fid])


# ------------------------------------------------------------------------------------ seam padding
def pad_seams(image: np.ndarray, mask: np.ndarray, gutter: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Fill a gutter around every chart from the nearest covered texel.

    Args:
        image: (H, W, C) texture (any dtype); mask: (H, W) bool texels that hold colour.
        gutter: width in texels of the band to fill (Euclidean distance to the nearest covered texel);
            ``gutter < 0`` fills the whole image.

    Returns:
        (padded image, (H, W) bool mask of texels that now hold colour).
    """
    image = np.asarray(image)
    mask = np.asarray(mask, dtype=bool)
    if image.ndim != 3 or image.shape[:2] != mask.shape:
        raise ValueError(f"image must be (H, W, C) matching mask {mask.shape}, got {image.shape}")
    if not mask.any():
        return image.copy(), mask.copy()
    dist, (ri, rj) = ndimage.distance_transform_edt(~mask, return_indices=True)
    fill = (~mask) if gutter < 0 else (~mask) & (dist <= gutter)
    out = image.copy()
    out[fill] = image[ri[fill], rj[fill]]
    return out, mask | fill


# ------------------------------------------------------------------------------------------ lookup
def texel_coords(uv: np.ndarray, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Continuous texel coordinates (row, col) of UVs, texel centres at integers: (n,), (n,) float64."""
    uv = np.asarray(uv, dtype=np.float64)
    return (1.0 - uv[:, 1]) * height - 0.5, uv[:, 0] * width - 0.5


def sample_texture(texture: np.ndarray, uv: np.ndarray, bilinear: bool = True) -> np.ndarray:
    """Colours (n, C) float64 of a texture (H, W, C) at UVs (n, 2) (clamped to the edge).

    uint8 textures are scaled to [0, 1]. Bilinear interpolation between the four nearest texel
    centres, or the nearest texel.
    """
    tex = np.asarray(texture)
    if tex.ndim != 3:
        raise ValueError(f"texture must be (H, W, C), got {tex.shape}")
    scale = 1.0 / 255.0 if tex.dtype == np.uint8 else 1.0
    H, W = tex.shape[:2]
    r, c = texel_coords(uv, H, W)
    if not bilinear:
        i = np.clip(np.round(r).astype(np.int64), 0, H - 1)
        j = np.clip(np.round(c).astype(np.int64), 0, W - 1)
        return tex[i, j].astype(np.float64) * scale
    r = np.clip(r, 0, H - 1)
    c = np.clip(c, 0, W - 1)
    i0 = np.minimum(np.floor(r).astype(np.int64), H - 2) if H > 1 else np.zeros(len(r), np.int64)
    j0 = np.minimum(np.floor(c).astype(np.int64), W - 2) if W > 1 else np.zeros(len(c), np.int64)
    fr = (r - i0)[:, None] if H > 1 else np.zeros((len(r), 1))
    fc = (c - j0)[:, None] if W > 1 else np.zeros((len(c), 1))
    # the four texels as rows of the flattened texture (take: half the time of tex[i, j]); i0 <= H - 2
    flat = tex.reshape(H * W, -1)
    k00 = i0 * W + j0
    down, right = (W if H > 1 else 0), (1 if W > 1 else 0)

    def at(k: np.ndarray) -> np.ndarray:  # the texels read, as float64 (not the whole texture)
        return flat.take(k, axis=0).astype(np.float64)

    top = at(k00) * (1 - fc) + at(k00 + right) * fc
    bot = at(k00 + down) * (1 - fc) + at(k00 + down + right) * fc
    return (top * (1 - fr) + bot * fr) * scale


def bilinear_corner(uv: np.ndarray, height: int, width: int) -> np.ndarray:
    """(n,) int64 row-major index of the first (top-left, clamped) of the four texels a bilinear
    lookup at each UV reads: with a map reduced over each texel's 2x2 block
    (:func:`bilinear_blocks`), one read answers for all four (:func:`bilinear_texels`)."""
    r, c = texel_coords(uv, height, width)
    i0 = np.clip(np.floor(r), 0, height - 1).astype(np.int64)
    j0 = np.clip(np.floor(c), 0, width - 1).astype(np.int64)
    return i0 * width + j0


def bilinear_blocks(grid: np.ndarray, reduce: str) -> np.ndarray:
    """(H, W) map of ``grid (H, W)`` over each texel's bilinear 2x2 block (the texel, its right and
    lower neighbours and the diagonal one, clamped at the last row and column, as
    :func:`bilinear_texels`): ``reduce`` "min", or "same" (the value where all four are equal,
    -1 where they differ; for non-negative labels)."""
    g = np.asarray(grid)
    if g.ndim != 2 or g.size == 0:
        raise ValueError(f"grid must be a non-empty (H, W) array, got {g.shape}")
    down = np.concatenate([g[1:], g[-1:]], axis=0)
    blocks = (g, np.concatenate([g[:, 1:], g[:, -1:]], axis=1), down, np.concatenate([down[:, 1:], down[:, -1:]], axis=1))
    if reduce == "min":
        return np.minimum.reduce(blocks)
    if reduce == "same":
        same = (blocks[0] == blocks[1]) & (blocks[0] == blocks[2]) & (blocks[0] == blocks[3])
        return np.where(same, g, -1).astype(g.dtype)
    raise ValueError(f"reduce must be 'min' or 'same', got {reduce!r}")


def bilinear_texels(uv: np.ndarray, height: int, width: int) -> np.ndarray:
    """(n, 4) int64 row-major indices of the texels a bilinear lookup at each UV reads (clamped)."""
    r, c = texel_coords(uv, height, width)
    i0 = np.clip(np.floor(r).astype(np.int64), 0, height - 1)
    j0 = np.clip(np.floor(c).astype(np.int64), 0, width - 1)
    i1 = np.clip(i0 + 1, 0, height - 1)
    j1 = np.clip(j0 + 1, 0, width - 1)
    return np.stack([i0 * width + j0, i0 * width + j1, i1 * width + j0, i1 * width + j1], axis=1)
