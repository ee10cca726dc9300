"""Parts (connected components) and part groups, within a shape and across shapes.

- :func:`segment`: connected components by *shared vertex indices* (scipy.sparse.csgraph),
  with per-part area, degenerate (zero-area) and tiny flags.
- :func:`group_parts`: repeated and mirrored parts of one shape share a group. Exact topology
  match first (vertex-to-vertex fit), else point-to-surface ICP from several starts (identity,
  reflections across the shape's detected symmetry planes, principal-axis frames) with a
  symmetric surface distance relative to the part's size. Every member keeps its rigid map onto
  the group representative (a reflection for mirrored parts).
- :func:`match_groups`: groups of a shape against the template's groups: topology fast path,
  else ICP in normalised part frames with a rotation penalty, plus position and size terms,
  solved as one assignment problem (scipy's ``linear_sum_assignment``), reporting matched, added
  and missing groups.

The normalised part frame (docs/correspondence.md): points minus the part's bounding-box centre, divided by its
L∞ radius (max |coordinate|).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from .align import affine_fit, apply, icp_to_surface, umeyama
from .shape import Shape
from .surface import SurfaceIndex, normalised_frame, sample_surface, triangle_areas


# ---------------------------------------------------------------------------------------- segment
@dataclass
class PartInfo:
    """One connected component.

    Attributes:
        index: part id (components are numbered by their first face).
        faces: (k,) int64 face indices into the shape.
        vertices: (j,) int64 sorted vertex indices into the shape.
        area: total surface area.
        degenerate: every triangle has (numerically) zero area.
        tiny: area below ``tiny_share`` of the shape's total area (and not degenerate).
        center: (3,) bounding-box centre; radius: L∞ radius around it (> 0 unless a single point).
        label: semantic label when the shape carries labels (majority of its vertices), else "".
        local: (k, 3) int64 read-only: the faces in local vertex indices (vertex i is
            ``vertices[i]``), as :func:`segment` made them (:func:`part_mesh` returns them), or None.
    """

    index: int
    faces: np.ndarray
    vertices: np.ndarray
    area: float
    degenerate: bool
    tiny: bool
    center: np.ndarray
    radius: float
    label: str = ""
    local: np.ndarray | None = field(default=None, repr=False, compare=False)

    @property
    def n_faces(self) -> int:
        return len(self.faces)


@dataclass
class Segmentation:
    """``face_part (m,) int64``, ``vertex_part (n,) int64`` (-1: unreferenced), ``parts``."""

    face_part: np.ndarray
    vertex_part: np.ndarray
    parts: list[PartInfo]

    @property
    def n_parts(self) -> int:
        return len(self.parts)


def connected_parts(faces: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Components of the face-vertex graph by shared vertex index.

    Returns:
        ``(face_part (m,) int64, vertex_part (n,) int64 with -1 for unreferenced, count)``; parts are
        numbered in order of their first face. Compiled (:mod:`proctex.geometry.mesh_kernels`:
        union-find in one pass), the same answer as :func:`connected_parts_arrays` (a sparse
        graph's components), which answers where numba does not import.
    """
    try:
        from .mesh_kernels import connected_parts as compiled
    except ImportError:
        return connected_parts_arrays(faces, n_vertices)
    return compiled(faces, n_vertices)


def connected_parts_arrays(faces: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray, int]:
    """:func:`connected_parts` by scipy's connected components (the compiled form's reference)."""
    faces = np.asarray(faces, dtype=np.int64)
    m = len(faces)
    if m == 0:
        return np.zeros(0, np.int64), -np.ones(n_vertices, np.int64), 0
    rows = np.repeat(faces[:, 0], 2)
    cols = faces[:, 1:].reshape(-1)
    graph = coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(n_vertices, n_vertices))
    _, vlab = connected_components(graph, directed=False)
    flab = vlab[faces[:, 0]]
    # Renumber by first face so part ids are stable and independent of vertex order.
    uniq, first = np.unique(flab, return_index=True)
    order = np.argsort(first)
    remap = -np.ones(vlab.max() + 1, dtype=np.int64)
    remap[uniq[order]] = np.arange(len(uniq))
    used = np.zeros(n_vertices, dtype=bool)
    used[faces.reshape(-1)] = True
    vertex_part = np.where(used, remap[vlab], -1)
    return remap[flab], vertex_part, len(uniq)


def segment(shape: Shape, degenerate_eps: float = 1e-12, tiny_share: float = 1e-4) -> Segmentation:
    """Split a shape into parts (connected components by shared vertex index).

    Args:
        shape: the mesh.
        degenerate_eps: a triangle is degenerate when its area is below ``degenerate_eps`` times the
            squared bounding-box diagonal of the shape.
        tiny_share: a non-degenerate part is tiny when its area is below this share of the total.
    """
    v, f = shape.vertices, shape.faces
    if len(f) == 0:
        raise ValueError("cannot segment a shape with no faces")
    face_part, vertex_part, count = connected_parts(f, len(v))
    areas = triangle_areas(v, f)
    used_pts = v[vertex_part >= 0]  # the vertices the faces use
    diag = float(np.linalg.norm(used_pts.max(0) - used_pts.min(0)))
    tri_eps = degenerate_eps * max(diag, 1e-300) ** 2
    part_area = np.bincount(face_part, weights=areas, minlength=count)
    total = part_area.sum()
    face_order = np.argsort(face_part, kind="stable")
    face_ends = np.cumsum(np.bincount(face_part, minlength=count))
    face_splits = np.split(face_order, face_ends[:-1])
    # every part has a face: its largest triangle by one pass over the faces in part order
    part_max_tri = np.maximum(np.maximum.reduceat(areas[face_order], np.concatenate([[0], face_ends[:-1]])), 0.0)
    vert_order = np.argsort(vertex_part, kind="stable")
    n_unref = int((vertex_part < 0).sum())
    vert_splits = np.split(vert_order[n_unref:], np.cumsum(np.bincount(vertex_part[vertex_part >= 0], minlength=count))[:-1])
    parts = []
    rank = np.zeros(len(v), np.int64)  # each used vertex's place in its part's vertices
    for vs in vert_splits:  # sorted already: a stable argsort keeps each part's vertices in index order
        rank[vs] = np.arange(len(vs))
    local_faces = rank[f]
    for i in range(count):
        center, radius = normalised_frame(v[vert_splits[i]])
        degenerate = bool(part_max_tri[i] <= tri_eps)
        label = ""
        if shape.labels is not None:
            label = shape.label_names[int(np.bincount(shape.labels[vert_splits[i]]).argmax())]
        parts.append(
            PartInfo(
                index=i,
                faces=face_splits[i],
                vertices=vert_splits[i],
                area=float(part_area[i]),
                degenerate=degenerate,
                tiny=bool(not degenerate and part_area[i] < tiny_share * total),
                center=center,
                radius=radius,
                label=label,
                local=_read_only(local_faces[face_splits[i]]),
            )
        )
    return Segmentation(face_part, vertex_part, parts)


def _read_only(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


def kind_groups(shape: Shape, segmentation: Segmentation | None = None, tol: float = 0.15) -> Grouping:
    """A quick grouping of a shape's parts by kind: non-degenerate, non-tiny parts whose bounding-box
    extents (per axis, relative to the shape's largest extent) agree within ``tol`` relatively share
    a group (four legs, a mirrored pair of arms); degenerate and tiny parts are groups of their own,
    marked degenerate. No rigid matching (members carry no maps): a cheap stand-in for
    :func:`group_parts` where only what the parts are matters (part words, template coverage)."""
    seg = segmentation if segmentation is not None else segment(shape)
    v = shape.vertices
    used = np.unique(shape.faces)
    longest = float(np.ptp(v[used], axis=0).max()) or 1.0
    keys: list[np.ndarray] = []
    groups: list[PartGroup] = []
    part_group = np.full(len(seg.parts), -1, dtype=np.int64)
    for p in seg.parts:
        skip = p.degenerate or p.tiny
        e = np.log(np.maximum(np.ptp(v[p.vertices], axis=0) / longest, 1e-6))
        hit = None if skip else next((k for k, r in enumerate(keys) if r is not None and np.all(np.abs(e - r) <= np.log1p(tol))), None)
        if hit is None:
            keys.append(None if skip else e)
            groups.append(PartGroup(len(groups), [p.index], [], bool(skip), p.label))
            hit = len(groups) - 1
        else:
            groups[hit].members.append(p.index)
        part_group[p.index] = hit
    return Grouping(seg, groups, part_group)


def part_kinds(shape: Shape, segmentation: Segmentation | None = None, tol: float = 0.15) -> int:
    """How many kinds of part a shape has (the non-degenerate groups of :func:`kind_groups`): used
    to pick a template that carries the optional parts of a family (a chair with its back and arms)."""
    return sum(not g.degenerate for g in kind_groups(shape, segmentation, tol).groups)


def part_mesh(shape: Shape, part: PartInfo) -> tuple[np.ndarray, np.ndarray]:
    """Local ``(vertices (j, 3), faces (k, 3))`` of a part; local vertex i is ``part.vertices[i]``.
    The faces are the part's own read-only :attr:`PartInfo.local` where :func:`segment` made them,
    else found here."""
    local = part.local if part.local is not None else np.searchsorted(part.vertices, shape.faces[part.faces])
    return shape.vertices[part.vertices], local


# ------------------------------------------------------------------------------------- part models
@dataclass
class _PartGeom:
    """Cached per-part geometry used by grouping and matching."""

    info: PartInfo
    vertices: np.ndarray  # (j, 3)
    faces: np.ndarray  # (k, 3) local
    topo_key: bytes  # orientation-free local topology
    samples: np.ndarray  # (s, 3) surface samples
    index: SurfaceIndex
    extents: np.ndarray  # (3,) sorted principal extents (sqrt of covariance eigenvalues), descending
    axes: np.ndarray  # (3, 3) principal axes as columns
    moments: np.ndarray  # (3,) the same from the exact area-weighted second moment of the surface (no sampling noise)
    tree: Any = None  # cKDTree of ``samples`` (ranks ICP starts)


def _part_geom(shape: Shape, part: PartInfo, n_samples: int, seed: int) -> _PartGeom:
    v, f = part_mesh(shape, part)
    key = np.sort(f, axis=1)
    samples, _, _ = sample_surface(v, f, n_samples, seed=seed)
    cov = np.cov((samples - samples.mean(0)).T)
    evals, evecs = np.linalg.eigh(cov)
    order = np.argsort(evals)[::-1]
    return _PartGeom(
        info=part,
        vertices=v,
        faces=f,
        topo_key=len(v).to_bytes(8, "little") + key.tobytes(),
        samples=samples,
        index=SurfaceIndex(v, f),
        extents=np.sqrt(np.maximum(evals[order], 0)),
        axes=evecs[:, order],
        moments=surface_moments(v, f),
        tree=cKDTree(samples),
    )


def surface_moments(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(3,) descending square roots of the eigenvalues of a surface's area-weighted covariance,
    exact per triangle (``A/12 (a a' + b b' + c c' + s s')``, ``s = a + b + c``): the same for every
    rigid or mirrored copy up to rounding, unlike sampled extents."""
    v = np.asarray(vertices, dtype=np.float64)
    tri = v[np.asarray(faces)]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    total = area.sum()
    if total <= 0:
        return np.zeros(3)
    s = tri.sum(axis=1)
    mean = (area[:, None] * s).sum(0) / (3 * total)
    second = (np.einsum("t,tki,tkj->ij", area, tri, tri) + np.einsum("t,ti,tj->ij", area, s, s)) / (12 * total)
    evals = np.linalg.eigvalsh(second - np.outer(mean, mean))
    return np.sqrt(np.maximum(evals[::-1], 0.0))


def _reflection(normal: np.ndarray) -> np.ndarray:
    n = normal / np.linalg.norm(normal)
    return np.eye(3) - 2 * np.outer(n, n)


@dataclass
class SymmetryPlane:
    """A mirror plane ``{x : normal·x = offset}`` of a whole shape; ``error`` relative to its size."""

    normal: np.ndarray
    offset: float
    error: float


def symmetry_planes(shape: Shape, tol: float = 0.01, n_samples: int = 1000, seed: int = 0) -> list[SymmetryPlane]:
    """Mirror planes of the whole shape among the coordinate and principal planes through its centre.

    A plane is accepted when the mean distance from the reflected surface samples to the surface
    is below ``tol`` times the shape's L∞ radius.
    """
    v, f = shape.vertices, shape.faces
    rng = np.random.default_rng(seed)
    pts, _, _ = sample_surface(v, f, n_samples, seed=rng)
    dense, _, _ = sample_surface(v, f, 4 * n_samples, seed=rng)
    center, radius = normalised_frame(v[np.unique(f)])
    radius = max(radius, 1e-12)
    _, evecs = np.linalg.eigh(np.cov((pts - pts.mean(0)).T))
    candidates = list(np.eye(3)) + [evecs[:, i] for i in range(3)]
    tree = cKDTree(dense)
    floor = float(tree.query(pts)[0].mean())  # sampling noise of the cheap test
    index: SurfaceIndex | None = None
    found: list[SymmetryPlane] = []
    for n in candidates:
        if any(abs(np.dot(n, p.normal)) > 0.99 for p in found):
            continue
        mirrored = (pts - center) @ _reflection(n).T + center
        # Cheap rejection against dense samples before the exact surface distance.
        if float(tree.query(mirrored)[0].mean()) > floor + 3 * tol * radius:
            continue
        index = index or SurfaceIndex(v, f)
        err = float(index.query(mirrored).distance.mean()) / radius
        if err < tol:
            found.append(SymmetryPlane(n.copy(), float(np.dot(n, center)), err))
    return found


# -------------------------------------------------------------------------------------- grouping
@dataclass
class MemberMap:
    """How a group member lies on its representative.

    ``R (3, 3)``, ``t (3,)``: ``x_rep = R x_member + t`` (det R < 0 for a mirrored member);
    ``R`` is a rotation (or reflection) times the member's uniform ``scale`` (1 but for
    "similar" members), or for a "deformed" member the best affine fit. ``method``: "self",
    "topology" (vertex i ↔ vertex i), "similar" (vertex i ↔ vertex i of a uniformly scaled copy:
    an instance a procedural model scaled), "deformed" (vertex i ↔ vertex i of a copy the model
    moved vertex by vertex: the correspondence is the shared connectivity, ``R, t`` only
    approximate it) or "icp"; ``error``: mean distance after the map ``R, t``, relative to the
    representative's L∞ radius.
    """

    part: int
    R: np.ndarray
    t: np.ndarray
    method: str
    error: float

    @property
    def mirrored(self) -> bool:
        return bool(np.linalg.det(self.R) < 0)

    @property
    def scale(self) -> float:
        """The map's uniform scale, ``|det R|^(1/3)`` (1 for a rigid map)."""
        return float(abs(np.linalg.det(np.asarray(self.R, dtype=np.float64))) ** (1.0 / 3.0))

    @property
    def rotation(self) -> np.ndarray:
        """The map's rotation (or reflection) alone ``(3, 3)``, the map between the member's and the
        representative's normalised frames (each part's own centre and radius): ``R / scale``, or
        for a "deformed" member the orthogonal factor of ``R`` (its polar decomposition)."""
        R = np.asarray(self.R, dtype=np.float64)
        if self.method == "deformed":
            U, _, Vt = np.linalg.svd(R)
            return U @ Vt
        s = self.scale
        return R / (s if s > 0 else 1.0)

    def inverse(self, points: np.ndarray) -> np.ndarray:
        """Representative-frame ``points (k, 3)`` back on the member: ``R^-1 (x - t)``."""
        return np.linalg.solve(np.asarray(self.R, dtype=np.float64), (np.asarray(points, dtype=np.float64) - self.t).T).T


@dataclass
class PartGroup:
    """Parts that share one texture. ``members[0]`` is the representative."""

    index: int
    members: list[int]
    maps: list[MemberMap]
    degenerate: bool
    label: str = ""

    @property
    def representative(self) -> int:
        return self.members[0]


@dataclass
class Grouping:
    """Parts and groups of one shape. ``part_group (P,) int64``."""

    segmentation: Segmentation
    groups: list[PartGroup]
    part_group: np.ndarray
    symmetry: list[SymmetryPlane] = field(default_factory=list)

    @property
    def parts(self) -> list[PartInfo]:
        return self.segmentation.parts

    def names(self, group: PartGroup) -> list[str]:
        """The distinct labels of a group's members, the representative's first ("Left Arm", "Right
        Arm" for a mirrored pair a node tree names apart); [] when none carries one."""
        return list(dict.fromkeys(lab for i in group.members if (lab := self.parts[i].label)))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary: ``{"parts": [...], "groups": [...], "symmetry_planes": [...]}``."""
        parts = [
            {
                "index": p.index,
                "faces": int(p.n_faces),
                "vertices": int(len(p.vertices)),
                "area": float(p.area),
                "degenerate": bool(p.degenerate),
                "tiny": bool(p.tiny),
                "group": int(self.part_group[p.index]),
                "center": [float(x) for x in p.center],
                "radius": float(p.radius),
                **({"label": p.label} if p.label else {}),
            }
            for p in self.parts
        ]
        groups = [
            {
                "index": g.index,
                "parts": [int(i) for i in g.members],
                "representative": int(g.representative),
                "degenerate": bool(g.degenerate),
                "mirrored": [int(m.part) for m in g.maps if m.mirrored],
                "methods": [m.method for m in g.maps],
                "errors": [float(m.error) for m in g.maps],
                "maps": [{"part": int(m.part), "R": np.asarray(m.R, dtype=float).tolist(), "t": np.asarray(m.t, dtype=float).tolist(), "method": m.method, "error": float(m.error)} for m in g.maps],
                **({"label": g.label} if g.label else {}),
                **({"names": self.names(g)} if len(self.names(g)) > 1 else {}),
            }
            for g in self.groups
        ]
        planes = [{"normal": [float(x) for x in s.normal], "offset": float(s.offset), "error": float(s.error)} for s in self.symmetry]
        return {"parts": parts, "groups": groups, "symmetry_planes": planes}

    @classmethod
    def from_dict(cls, data: dict[str, Any], segmentation: Segmentation) -> "Grouping":
        """The grouping :meth:`to_dict` wrote, on ``segmentation`` (the same shape's :func:`segment`):
        groups, member maps and symmetry planes as they were, not analysed again. ``ValueError``
        when the record has no member maps (written before they were stored) or does not fit the
        segmentation."""
        try:
            groups = []
            for g in data["groups"]:
                if "maps" not in g:
                    raise ValueError("the stored grouping has no member maps (written by an older version)")
                maps = [
                    MemberMap(int(m["part"]), np.asarray(m["R"], dtype=np.float64).reshape(3, 3), np.asarray(m["t"], dtype=np.float64).reshape(3), str(m["method"]), float(m["error"]))
                    for m in g["maps"]
                ]
                groups.append(PartGroup(int(g["index"]), [int(i) for i in g["parts"]], maps, bool(g["degenerate"]), str(g.get("label", ""))))
            planes = [SymmetryPlane(np.asarray(q["normal"], dtype=np.float64).reshape(3), float(q["offset"]), float(q["error"])) for q in data.get("symmetry_planes", [])]
        except (KeyError, TypeError) as exc:
            raise ValueError(f"malformed stored grouping ({exc.__class__.__name__}: {exc})") from exc
        n = segmentation.n_parts
        members = sorted(i for g in groups for i in g.members)
        if members != list(range(n)) or [g.index for g in groups] != list(range(len(groups))):
            raise ValueError(f"the stored grouping does not fit the shape: {n} parts, groups cover {members[:10]}")
        if any([m.part for m in g.maps] != g.members for g in groups):
            raise ValueError("the stored grouping's member maps do not follow its members")
        part_group = np.empty(n, dtype=np.int64)
        for g in groups:
            part_group[g.members] = g.index
        return cls(segmentation, groups, part_group, planes)


#: A part whose exact principal extents (:func:`surface_moments`) differ from a representative's by
#: more than this many ``tol`` (relative to the larger first extent) is no rigid copy of it: a mean
#: surface distance below ``tol`` x radius moves an RMS extent by at most about 3.5 ``tol``.
MOMENT_TOLS = 4.0
#: Most rigid matches (ICP) a part is tried against, nearest groups by extents first: a shape of
#: thousands of similar but different parts is grouped in bounded time.
MAX_MATCH_TRIES = 6
#: ICP refinements per match, from the starting maps nearest by sampled distance.
ICP_STARTS = 3
#: Above this many parts (a scene's bricks and leaves, made by instancing) copies are found through
#: their shared connectivity only, without ICP: grouping stays near a millisecond per part.
ICP_PARTS = 300


#: A "deformed" copy (above :data:`ICP_PARTS` parts) has the representative's vertex count and at
#: least this share of its faces on the same local vertices: an exporter that splits each quad of a
#: moved copy along its shorter diagonal flips a few of them (a bent trunk: 8 of 156 faces).
DEFORMED_SHARED = 0.75


def shared_faces(fa: np.ndarray, fb: np.ndarray) -> float:
    """Share of the faces ``fa (k, 3)`` whose vertex set is a face of ``fb (m, 3)`` too (local
    vertex indices, any corner order), in [0, 1]; 0 for no faces."""
    if len(fa) == 0:
        return 0.0
    qa, qb = np.sort(np.asarray(fa, dtype=np.int64), axis=1), np.sort(np.asarray(fb, dtype=np.int64), axis=1)
    n = int(max(qa.max(), qb.max() if len(qb) else 0)) + 1
    if n >= 2_000_000:  # n^3 would overflow int64: compare the rows as tuples
        rows = set(map(tuple, qb.tolist()))
        return float(np.mean([tuple(r) in rows for r in qa.tolist()]))
    code = lambda q: (q[:, 0] * n + q[:, 1]) * n + q[:, 2]  # noqa: E731
    return float(np.isin(code(qa), code(qb)).mean())


def _compatible(a: _PartGeom, b: _PartGeom, rel: float, tol: float = 0.01) -> bool:
    # Degenerate parts carry no surface to texture: each stays in a group of its own.
    if a.info.degenerate or b.info.degenerate:
        return False
    big = max(a.info.area, b.info.area)
    if abs(a.info.area - b.info.area) > rel * big:
        return False
    scale = max(a.extents[0], b.extents[0], 1e-300)
    if not np.all(np.abs(a.extents - b.extents) <= rel * scale):
        return False
    exact = max(a.moments[0], b.moments[0], 1e-300)
    return bool(np.all(np.abs(a.moments - b.moments) <= MOMENT_TOLS * tol * exact))


def _init_rotations(a: _PartGeom, b: _PartGeom, planes: list[SymmetryPlane]) -> list[np.ndarray]:
    """Candidate linear maps (member -> representative) to start ICP from."""
    cands = [np.eye(3)]
    cands += [_reflection(p.normal) for p in planes]
    cands += [_reflection(ax) for ax in np.eye(3)]
    for signs in np.array(np.meshgrid([1, -1], [1, -1], [1, -1])).T.reshape(-1, 3):
        cands.append(b.axes @ np.diag(signs) @ a.axes.T)
    return cands


def _surface_error(a: _PartGeom, b: _PartGeom, R: np.ndarray, t: np.ndarray) -> float:
    """Symmetric mean distance between ``R a + t`` and ``b``, relative to b's L∞ radius."""
    ab = b.index.query(apply(a.samples, R, t)).distance.mean()
    ba = a.index.query((b.samples - t) @ R).distance.mean()  # inverse map R^T (x - t)
    return float(0.5 * (ab + ba) / max(b.info.radius, 1e-300))


def match_part_rigid(a: _PartGeom, b: _PartGeom, planes: list[SymmetryPlane], tol: float, icp: bool = True, similar: bool = False, deformed: bool = False) -> MemberMap | None:
    """Rigid (or mirrored) map of part ``a`` onto part ``b`` with surface error below ``tol``, or None.
    ``icp=False``: only the map through their shared connectivity (copies that keep their vertex
    order, as instancing makes them). ``similar``: a copy with the same connectivity may also be
    uniformly scaled (method "similar"; its map's ``R`` carries the scale). ``deformed``: a copy
    with the same connectivity is a member whatever its shape (method "deformed", ``R, t`` the
    best affine fit, its error whatever it is)."""
    if a.topo_key == b.topo_key:
        R, t, _ = umeyama(a.vertices, b.vertices, reflection=None)
        err = float(np.linalg.norm(apply(a.vertices, R, t) - b.vertices, axis=1).mean() / max(b.info.radius, 1e-300))
        if err < tol:
            return MemberMap(a.info.index, R, t, "topology", err)
        if similar:
            R, t, s = umeyama(a.vertices, b.vertices, scale=True, reflection=None)
            if np.isfinite(s) and s > 0:
                err = float(np.linalg.norm(apply(a.vertices, R, t, s) - b.vertices, axis=1).mean() / max(b.info.radius, 1e-300))
                if err < tol:
                    return MemberMap(a.info.index, s * R, t, "similar", err)
    if deformed and len(a.vertices) == len(b.vertices) and shared_faces(a.faces, b.faces) >= DEFORMED_SHARED:
        A, t, fitted = affine_fit(a.vertices, b.vertices)
        if np.all(np.isfinite(A)):
            err = float(np.linalg.norm(fitted - b.vertices, axis=1).mean() / max(b.info.radius, 1e-300))
            return MemberMap(a.info.index, A, t, "deformed", err)
    if a.topo_key == b.topo_key:
        return None  # the same indexed mesh: the map through its vertices is the best rigid map there is
    if not icp:
        return None
    ca, cb = a.samples.mean(0), b.samples.mean(0)
    # Rank the starting maps by a cheap nearest-sample distance and refine only the best few by
    # ICP to the exact surface (each ICP is ~30 exact closest-point queries of every sample).
    tree = b.tree if b.tree is not None else cKDTree(b.samples)
    # Starts as good as the best (within its sampling noise and tol) keep their order (the identity
    # first: a symmetric part's copy stays a translated copy, not a mirrored one).
    starts = [(float(tree.query(apply(a.samples, R0, cb - R0 @ ca))[0].mean()), R0) for R0 in _init_rotations(a, b, planes)]
    best = min(d for d, _ in starts)
    good = [R0 for d, R0 in starts if d <= 1.5 * best + tol * max(b.info.radius, 1e-300)]
    for R0 in good[:ICP_STARTS]:
        res = icp_to_surface(a.samples, b.index, R0=R0, t0=cb - R0 @ ca, max_iter=30)
        if res.error / max(b.info.radius, 1e-300) > 2 * tol:
            continue
        err = _surface_error(a, b, res.R, res.t)
        if err < tol:
            return MemberMap(a.info.index, res.R, res.t, "icp", err)
    return None


def group_parts(
    shape: Shape,
    segmentation: Segmentation | None = None,
    tol: float = 0.01,
    prefilter: float = 0.1,
    n_samples: int = 400,
    seed: int = 0,
    similar: bool = True,
) -> Grouping:
    """Group the repeated and mirrored parts of a shape.

    Args:
        shape: the mesh.
        segmentation: from :func:`segment` (computed when omitted).
        tol: a (non-degenerate) part joins a group when its symmetric mean surface distance to the representative,
            after the best rigid or mirrored map, is below ``tol`` × the representative's L∞ radius.
        prefilter: parts whose areas or principal extents differ by more than this share are never
            compared (nor those whose exact extents differ by more than :data:`MOMENT_TOLS` x ``tol``);
            a part is matched against at most :data:`MAX_MATCH_TRIES` groups, the nearest by extents;
            above :data:`ICP_PARTS` parts only copies with the same connectivity are found.
        n_samples: surface samples per part.
        seed: sampling seed.
        similar: a part that joins no group rigidly joins the group of a uniformly scaled copy of it
            (the same indexed mesh, vertex for vertex, within ``tol`` after the best similarity):
            the instances a procedural model scales (a scattered set's leaves) share one texture.
            Above :data:`ICP_PARTS` parts (a scene made by instancing), a part that is neither joins
            the group of any part with its connectivity, vertex for vertex, however the model moved
            its vertices (method "deformed": a scattered set's trunks, each bent its own way): a
            scene's instances share their textures, and its groups stay as few as its meshes.
            Parts of other connectivity are compared rigidly only.
    """
    seg = segmentation if segmentation is not None else segment(shape)
    planes = symmetry_planes(shape, seed=seed) if seg.n_parts > 1 else []
    geoms = [_part_geom(shape, p, n_samples, seed + p.index) for p in seg.parts]
    groups: list[PartGroup] = []
    part_group = -np.ones(seg.n_parts, dtype=np.int64)
    icp = sum(not p.degenerate for p in seg.parts) <= ICP_PARTS
    by_topo: dict[bytes, list[PartGroup]] = {}  # groups by their representative's connectivity
    by_count: dict[int, list[PartGroup]] = {}  # ... and by its vertex count
    for g in geoms:

        def size_gap(grp: PartGroup) -> float:  # how far a group's representative is from g's size
            return abs(np.log(max(geoms[grp.representative].info.radius, 1e-300) / max(g.info.radius, 1e-300)))

        def tries():  # (group, match_part_rigid's options), in order; the later ones only if the earlier fail
            near = [grp for grp in groups if _compatible(g, geoms[grp.representative], prefilter, tol)]
            near.sort(key=lambda grp: float(np.abs(g.moments - geoms[grp.representative].moments).sum()))
            yield from ((grp, {"icp": icp}) for grp in near[:MAX_MATCH_TRIES])
            if similar and not g.info.degenerate:
                # scaled copies fail the size prefilter: the groups of the same connectivity, nearest size first
                same = sorted(by_topo.get(g.topo_key, []), key=size_gap)[:MAX_MATCH_TRIES]
                yield from ((grp, {"icp": False, "similar": True}) for grp in same)
                if not icp:  # then a copy the model moved vertex by vertex, of the nearest size first
                    alike = sorted(by_count.get(len(g.vertices), []), key=size_gap)[:MAX_MATCH_TRIES]
                    yield from ((grp, {"icp": False, "similar": True, "deformed": True}) for grp in alike)

        placed = False
        for grp, options in tries():
            mm = match_part_rigid(g, geoms[grp.representative], planes, tol, **options)
            if mm is not None:
                grp.members.append(g.info.index)
                grp.maps.append(mm)
                part_group[g.info.index] = grp.index
                placed = True
                break
        if not placed:
            gi = len(groups)
            groups.append(PartGroup(gi, [g.info.index], [MemberMap(g.info.index, np.eye(3), np.zeros(3), "self", 0.0)], g.info.degenerate, g.info.label))
            part_group[g.info.index] = gi
            if not g.info.degenerate:
                by_topo.setdefault(g.topo_key, []).append(groups[-1])
                by_count.setdefault(len(g.vertices), []).append(groups[-1])
    return Grouping(seg, groups, part_group, planes)


def parts_of(shape: Shape) -> Segmentation:
    """:func:`segment` of ``shape`` with the default settings, computed once and kept on the shape
    (a request checks, transfers and bakes one segmentation). Computed again when the shape's vertex
    or face array was replaced; an array changed in place is not seen."""
    cached = shape.derived.get("parts")
    if cached is not None and cached[0] is shape.faces and cached[1] is shape.vertices:
        return cached[2]
    seg = segment(shape)
    shape.derived["parts"] = (shape.faces, shape.vertices, seg)
    return seg


def analyse(shape: Shape, **kwargs: Any) -> Grouping:
    """Segment and group a shape in one call (keyword arguments go to :func:`group_parts`)."""
    return group_parts(shape, segment(shape), **kwargs)
