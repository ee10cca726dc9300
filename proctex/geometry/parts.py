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

The normalised part frame (DESIGN §6): points minus the part's bounding-box centre, divided by its
L∞ radius (max |coordinate|).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from .align import apply, icp_points, icp_to_surface, rotation_angle, umeyama
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
        numbered in order of their first face.
    """
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
    used_pts = v[np.unique(f)]
    diag = float(np.linalg.norm(used_pts.max(0) - used_pts.min(0)))
    tri_eps = degenerate_eps * max(diag, 1e-300) ** 2
    part_area = np.bincount(face_part, weights=areas, minlength=count)
    part_max_tri = np.zeros(count)
    np.maximum.at(part_max_tri, face_part, areas)
    total = part_area.sum()
    face_order = np.argsort(face_part, kind="stable")
    face_splits = np.split(face_order, np.cumsum(np.bincount(face_part, minlength=count))[:-1])
    vert_order = np.argsort(vertex_part, kind="stable")
    n_unref = int((vertex_part < 0).sum())
    vert_splits = np.split(vert_order[n_unref:], np.cumsum(np.bincount(vertex_part[vertex_part >= 0], minlength=count))[:-1])
    parts = []
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
                vertices=np.sort(vert_splits[i]),
                area=float(part_area[i]),
                degenerate=degenerate,
                tiny=bool(not degenerate and part_area[i] < tiny_share * total),
                center=center,
                radius=radius,
                label=label,
            )
        )
    return Segmentation(face_part, vertex_part, parts)


def part_mesh(shape: Shape, part: PartInfo) -> tuple[np.ndarray, np.ndarray]:
    """Local ``(vertices (j, 3), faces (k, 3))`` of a part; local vertex i is ``part.vertices[i]``."""
    local = np.searchsorted(part.vertices, shape.faces[part.faces])
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
    )


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

    ``R (3, 3)``, ``t (3,)``: ``x_rep = R x_member + t`` (det R = -1 for a mirrored member);
    ``method``: "self", "topology" (vertex i ↔ vertex i) or "icp"; ``error``: mean surface
    distance after the map, relative to the representative's L∞ radius.
    """

    part: int
    R: np.ndarray
    t: np.ndarray
    method: str
    error: float

    @property
    def mirrored(self) -> bool:
        return bool(np.linalg.det(self.R) < 0)


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
                "maps": [{"part": int(m.part), "R": np.asarray(m.R, dtype=float).tolist(), "t": np.asarray(m.t, dtype=float).tolist(),
                          "method": m.method, "error": float(m.error)} for m in g.maps],
                **({"label": g.label} if g.label else {}),
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
                maps = [MemberMap(int(m["part"]), np.asarray(m["R"], dtype=np.float64).reshape(3, 3), np.asarray(m["t"], dtype=np.float64).reshape(3),
                                  str(m["method"]), float(m["error"])) for m in g["maps"]]
                groups.append(PartGroup(int(g["index"]), [int(i) for i in g["parts"]], maps, bool(g["degenerate"]), str(g.get("label", ""))))
            planes = [SymmetryPlane(np.asarray(q["normal"], dtype=np.float64).reshape(3), float(q["offset"]), float(q["error"]))
                      for q in data.get("symmetry_planes", [])]
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


def _compatible(a: _PartGeom, b: _PartGeom, rel: float) -> bool:
    # Degenerate parts carry no surface to texture: each stays in a group of its own.
    if a.info.degenerate or b.info.degenerate:
        return False
    big = max(a.info.area, b.info.area)
    if abs(a.info.area - b.info.area) > rel * big:
        return False
    scale = max(a.extents[0], b.extents[0], 1e-300)
    return bool(np.all(np.abs(a.extents - b.extents) <= rel * scale))


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


def match_part_rigid(a: _PartGeom, b: _PartGeom, planes: list[SymmetryPlane], tol: float) -> MemberMap | None:
    """Rigid (or mirrored) map of part ``a`` onto part ``b`` with surface error below ``tol``, or None."""
    if a.topo_key == b.topo_key:
        R, t, _ = umeyama(a.vertices, b.vertices, reflection=None)
        err = float(np.linalg.norm(apply(a.vertices, R, t) - b.vertices, axis=1).mean() / max(b.info.radius, 1e-300))
        if err < tol:
            return MemberMap(a.info.index, R, t, "topology", err)
    ca, cb = a.samples.mean(0), b.samples.mean(0)
    for R0 in _init_rotations(a, b, planes):
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
) -> Grouping:
    """Group the repeated and mirrored parts of a shape.

    Args:
        shape: the mesh.
        segmentation: from :func:`segment` (computed when omitted).
        tol: a (non-degenerate) part joins a group when its symmetric mean surface distance to the representative,
            after the best rigid or mirrored map, is below ``tol`` × the representative's L∞ radius.
        prefilter: parts whose areas or principal extents differ by more than this share are never
            compared.
        n_samples: surface samples per part.
        seed: sampling seed.
    """
    seg = segmentation if segmentation is not None else segment(shape)
    planes = symmetry_planes(shape, seed=seed) if seg.n_parts > 1 else []
    geoms = [_part_geom(shape, p, n_samples, seed + p.index) for p in seg.parts]
    groups: list[PartGroup] = []
    part_group = -np.ones(seg.n_parts, dtype=np.int64)
    for g in geoms:
        placed = False
        for grp in groups:
            rep = geoms[grp.representative]
            if not _compatible(g, rep, prefilter):
                continue
            mm = match_part_rigid(g, rep, planes, tol)
            if mm is not None:
                grp.members.append(g.info.index)
                grp.maps.append(mm)
                part_group[g.info.index] = grp.index
                placed = True
                break
        if not placed:
            gi = len(groups)
            groups.append(
                PartGroup(gi, [g.info.index], [MemberMap(g.info.index, np.eye(3), np.zeros(3), "self", 0.0)], g.info.degenerate, g.info.label)
            )
            part_group[g.info.index] = gi
    return Grouping(seg, groups, part_group, planes)


def analyse(shape: Shape, **kwargs: Any) -> Grouping:
    """Segment and group a shape in one call (keyword arguments go to :func:`group_parts`)."""
    return group_parts(shape, segment(shape), **kwargs)


# ------------------------------------------------------------------------------- group matching
@dataclass
class GroupMatch:
    """Groups of a shape matched to the template's.

    Attributes:
        pairs: list of ``(shape_group, template_group)``.
        added: shape groups with no template counterpart.
        missing: template groups absent from the shape.
        cost: (Gs, Gt) float64 matrix the assignment was solved on.
        methods: per pair, "topology" or "icp".
        threshold: cost above which a pair is not a match.
    """

    pairs: list[tuple[int, int]]
    added: list[int]
    missing: list[int]
    cost: np.ndarray
    methods: list[str]
    threshold: float

    def mapping(self) -> dict[int, int]:
        return dict(self.pairs)

    def to_dict(self) -> dict[str, Any]:
        return {
            "matched": [
                {"shape_group": int(a), "template_group": int(b), "cost": float(self.cost[a, b]), "method": m}
                for (a, b), m in zip(self.pairs, self.methods)
            ],
            "added": [int(i) for i in self.added],
            "missing": [int(i) for i in self.missing],
            "threshold": self.threshold,
        }


def _shape_box(shape: Shape) -> tuple[np.ndarray, np.ndarray]:
    pts = shape.vertices[np.unique(shape.faces)]
    return pts.min(0), pts.max(0)


def _group_descriptor(shape: Shape, grouping: Grouping, g: PartGroup, n_samples: int, seed: int) -> dict[str, Any]:
    """World placement (member centres, extents) and normalised surface samples of a group's representative."""
    part = grouping.parts[g.representative]
    v, f = part_mesh(shape, part)
    ext = (v.max(0) - v.min(0)) / 2
    scale = np.maximum(ext, 1e-3 * max(part.radius, 1e-300))  # per-axis normalisation, no division by 0
    vn = (v - part.center) / scale
    samples, _, _ = sample_surface(vn, f, n_samples, seed=seed)
    return {
        "topo_key": len(v).to_bytes(8, "little") + np.sort(f, axis=1).tobytes(),
        "vertices_n": vn,
        "samples": samples,
        "tree": cKDTree(samples),
        "extent": ext,
        "centers": np.array([grouping.parts[i].center for i in g.members]),
        "degenerate": g.degenerate,
    }


def _shape_term(a: dict[str, Any], b: dict[str, Any], w_rot: float) -> tuple[float, str]:
    """Distance of two representatives in per-axis normalised frames plus a rotation penalty.

    Equal topology: mean vertex distance after a rigid fit. Otherwise point-to-point ICP between
    surface samples and the symmetric mean nearest-sample distance (its floor is the sample
    spacing, small against the differences between distinct parts).
    """
    if a["topo_key"] == b["topo_key"]:
        R, t, _ = umeyama(a["vertices_n"], b["vertices_n"])
        surf = float(np.linalg.norm(apply(a["vertices_n"], R, t) - b["vertices_n"], axis=1).mean())
        method = "topology"
    else:
        res = icp_points(a["samples"], b["samples"], b["tree"], max_iter=20)
        R = res.R
        back = a["tree"].query((b["samples"] - res.t) @ res.R)[0].mean()
        surf = float(0.5 * (res.error + back))
        method = "icp"
    penalty = 1.0 if a["degenerate"] != b["degenerate"] else 0.0
    return surf + w_rot * rotation_angle(R) + penalty, method


def _placed(d: dict[str, Any], scale: np.ndarray, shift: np.ndarray, center: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Member centres (k, 3) and size (3,) of a group after ``x -> scale x + shift``, in a (center, radius) frame."""
    return (d["centers"] * scale + shift - center) / radius, d["extent"] * np.abs(scale) / radius


def _set_offsets(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each member of the smaller of two centre sets (k, 3) paired with its nearest in the other.

    Returns index arrays ``(ia, ib)`` into ``a`` and ``b``. Repeated parts vary in number across a
    family (4 or 6 legs), so a group is placed like another when each member of the smaller group
    has a counterpart nearby.
    """
    if len(a) <= len(b):
        return np.arange(len(a)), cKDTree(b).query(a)[1]
    ib, ia = np.arange(len(b)), cKDTree(a).query(b)[1]
    return ia, ib


def _fit_axis_map(src: np.ndarray, dst: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis weighted least squares ``dst ≈ scale * src + shift``; src, dst (k, 3), w (k,)."""
    scale, shift = np.ones(3), np.zeros(3)
    for k in range(3):
        A = np.stack([src[:, k], np.ones(len(src))], axis=1) * np.sqrt(w)[:, None]
        sol, *_ = np.linalg.lstsq(A, dst[:, k] * np.sqrt(w), rcond=None)
        scale[k], shift[k] = sol
    return scale, shift


def _solve_assignment(cost: np.ndarray, threshold: float) -> list[tuple[int, int]]:
    """Min-cost matching where any row or column may stay unmatched at cost ``threshold``."""
    na, nb = cost.shape
    big = threshold * 10 + 1.0
    padded = np.full((na + nb, nb + na), big)
    padded[:na, :nb] = np.where(np.isfinite(cost), np.minimum(cost, big), big)
    padded[:na, nb:] = np.where(np.eye(na) > 0, threshold, big)
    padded[na:, :nb] = np.where(np.eye(nb) > 0, threshold, big)
    padded[na:, nb:] = 0.0
    rows, cols = linear_sum_assignment(padded)
    return sorted((int(r), int(c)) for r, c in zip(rows, cols) if r < na and c < nb and cost[r, c] < threshold)


def match_groups(
    shape: Shape,
    grouping: Grouping,
    template: Shape,
    template_grouping: Grouping,
    threshold: float = 1.5,
    w_rot: float = 0.5,
    w_pos: float = 2.0,
    w_size: float = 0.5,
    n_samples: int = 300,
    rounds: int = 3,
    seed: int = 0,
) -> GroupMatch:
    """Match a shape's part groups to the template's as one assignment problem.

    The cost of a pair sums: the mean surface distance after ICP (or a vertex fit when the
    topologies are equal) of the representatives in per-axis normalised part frames, ``w_rot`` ×
    the ICP rotation angle (families keep their orientation), ``w_pos`` × the mean distance from
    each member of the smaller group to the nearest member of the other (repeated parts vary in
    number), and ``w_size`` × the summed |log| ratios of their extents. Positions and sizes are compared in the template's frame: the shape is first mapped
    by per-axis scale and shift taking its bounding box onto the template's, then, for up to
    ``rounds`` rounds, by the per-axis map fitted to the groups matched so far (so a part that
    appears or vanishes at the edge of the shape does not shift everything else). Pairs costing
    more than ``threshold`` are left unmatched (the shape group is *added*, the template group
    *missing*).
    """
    da = [_group_descriptor(shape, grouping, g, n_samples, seed) for g in grouping.groups]
    db = [_group_descriptor(template, template_grouping, g, n_samples, seed) for g in template_grouping.groups]
    shape_term = np.zeros((len(da), len(db)))
    methods = np.full((len(da), len(db)), "none", dtype=object)
    for i, a in enumerate(da):
        for j, b in enumerate(db):
            shape_term[i, j], methods[i, j] = _shape_term(a, b, w_rot)
    s_lo, s_hi = _shape_box(shape)
    t_lo, t_hi = _shape_box(template)
    t_center = (t_lo + t_hi) / 2
    t_radius = max(float((t_hi - t_lo).max()) / 2, 1e-300)
    box_src, box_dst = np.stack([s_lo, s_hi]), np.stack([t_lo, t_hi])
    scale, shift = _fit_axis_map(box_src, box_dst, np.ones(2))
    tb = [_placed(b, np.ones(3), np.zeros(3), t_center, t_radius) for b in db]
    pairs: list[tuple[int, int]] = []
    for _ in range(max(rounds, 1)):
        sa = [_placed(a, scale, shift, t_center, t_radius) for a in da]
        cost = shape_term.copy()
        for i, (ca, sz_a) in enumerate(sa):
            for j, (cb, sz_b) in enumerate(tb):
                ia, ib = _set_offsets(ca, cb)
                pos = np.linalg.norm(ca[ia] - cb[ib], axis=1).mean()
                size = np.abs(np.log((sz_a + 1e-3) / (sz_b + 1e-3))).sum()
                cost[i, j] += w_pos * pos + w_size * size
        new_pairs = _solve_assignment(cost, threshold)
        if new_pairs == pairs or not new_pairs:
            pairs = new_pairs or pairs
            break
        pairs = new_pairs
        # Refit the shape -> template map on the matched members (box corners as a weak prior).
        src, dst = [box_src], [box_dst]
        for i, j in pairs:
            ia, ib = _set_offsets(sa[i][0], tb[j][0])
            src.append(da[i]["centers"][ia])
            dst.append(db[j]["centers"][ib])
        n_pts = sum(len(x) for x in src[1:])
        scale, shift = _fit_axis_map(np.concatenate(src), np.concatenate(dst), np.r_[np.ones(2), np.full(n_pts, 2.0)])
    na, nb = cost.shape
    matched_a = {a for a, _ in pairs}
    matched_b = {b for _, b in pairs}
    return GroupMatch(
        pairs=pairs,
        added=[i for i in range(na) if i not in matched_a],
        missing=[j for j in range(nb) if j not in matched_b],
        cost=cost,
        methods=[str(methods[a, b]) for a, b in pairs],
        threshold=threshold,
    )
