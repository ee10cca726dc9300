"""Honest fidelity measures (docs/results.md): points tracked by a reference correspondence that never
depends on the method evaluated, and correspondence errors over all points.

**Tracked-point texture variance.** Points on the template (:func:`tracked_points`) are located on
every shape by a *tracker* that is the same for every method:

- ``canonical`` (built-in models, and ``.blend`` models whose node tree was read): the ground
  truth. Template and shape parts are paired by their semantic label and placement
  (:func:`match_parts_by_label`); inside a part, the point with the same canonical coordinates is
  the corresponding one (:func:`locate_canonical`). A ``.blend`` shape's canonical coordinates are
  each producing node's own box coordinates (:mod:`proctex.sources.provenance`), so its parts pair
  by the node that made most of them and a point's counterpart is looked up **only among faces of
  the same node** (:attr:`Shape.face_source`); a point whose node the template part lacks has no
  truth.
- ``vertex-index`` (folder families whose samples share one vertex order, as many procedural
  exports do): tracked points are the template's vertices, and vertex *i* of a shape is the truth
  of template vertex *i* (:func:`locate_vertex_index`).
- ``cage`` (no truth): the cage solver, solved once per (shape, group) as the build solves its
  pairs, inverted exactly (:func:`locate_by_map`); tracked points then lie on the group
  representatives, the parts the pairs cover.

Each method's output is read at those shape points (:func:`colours_at`): through its real-time UVs
into the template textures, or from its baked texture. The variance (:func:`tracked_variance`) is
the paper's: per point the standard deviation of the colour over the shapes, the template included,
averaged over RGB and points. A point whose face a method left untextured (a dropped part, a failed
shape) is **counted**, as the colour farthest from the template's there, never skipped.

**Correspondence error.** Shape points with a known truth (:func:`truth_samples`: uniform samples
with canonical coordinates, or every vertex under vertex-index truth) are mapped by a method (the
mapped vertices of its transfer, interpolated and projected onto the template representative) and
compared with the true template point (:func:`gt_errors`); against the stored cage pairs for the
pseudo-ground truth (:func:`pgt_errors`). Errors are Euclidean distances in the template
representative's normalised frame (L∞ radius 1); a point of a part the method dropped or put in a
group the truth does not allow scores :data:`FAIL_ERROR`. :func:`error_summary` reports the mean,
p95, p99 and the **maximum over all points** (the paper's "max point loss").
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

from proctex.geometry.parts import Grouping, Segmentation, part_mesh
from proctex.geometry.shape import Shape
from proctex.geometry.surface import SurfaceIndex, interpolate, sample_surface
from proctex.texture.uv import sample_texture

#: Trackers of the tracked-point variance, best first.
TRACKERS = ("canonical", "vertex-index", "cage")
#: Error of a point whose part a method dropped or put in a group the truth does not allow: the
#: width of the normalised frame (a wrong point on the right part is rarely farther).
FAIL_ERROR = 2.0


# ---------------------------------------------------------------------------------------- helpers
def incident_faces(faces: np.ndarray, n_vertices: int, face_ok: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One face per vertex: ``(face (n,) int64, corner (n,) int64)``, the first admissible face
    (``face_ok (m,) bool``) that uses the vertex and the corner it sits at; -1 for vertices no
    admissible face uses."""
    f = np.asarray(faces, dtype=np.int64)
    ok = np.ones(len(f), dtype=bool) if face_ok is None else np.asarray(face_ok, dtype=bool)
    fid = np.repeat(np.arange(len(f)), 3)[np.repeat(ok, 3)]
    corner = np.tile(np.arange(3), len(f))[np.repeat(ok, 3)]
    vert = f.reshape(-1)[np.repeat(ok, 3)]
    face = np.full(n_vertices, -1, dtype=np.int64)
    cor = np.full(n_vertices, -1, dtype=np.int64)
    uniq, first = np.unique(vert, return_index=True)
    face[uniq], cor[uniq] = fid[first], corner[first]
    return face, cor


def _one_hot(corner: np.ndarray) -> np.ndarray:
    bary = np.zeros((len(corner), 3))
    ok = corner >= 0
    bary[np.flatnonzero(ok), corner[ok]] = 1.0
    return bary


def _face_ok(seg: Segmentation) -> np.ndarray:
    """(m,) bool: faces of non-degenerate parts."""
    return ~np.array([p.degenerate for p in seg.parts], dtype=bool)[seg.face_part]


def _placement(shape: Shape, seg: Segmentation, parts: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
    """Centres and extents (len(parts), 3) of parts relative to the shape's bounding box."""
    lo, hi = shape.vertices.min(axis=0), shape.vertices.max(axis=0)
    size = np.maximum(hi - lo, 1e-12)
    c, e = [], []
    for p in parts:
        v = shape.vertices[seg.parts[p].vertices]
        plo, phi = v.min(axis=0), v.max(axis=0)
        c.append(((plo + phi) / 2 - lo) / size)
        e.append((phi - plo) / size)
    return np.reshape(c, (-1, 3)), np.reshape(e, (-1, 3))


def by_source(shape: Shape) -> bool:
    """Whether ``shape``'s canonical truth is keyed by source node (a ``.blend`` shape) rather than
    by part label (a built-in model's)."""
    return shape.face_source is not None


def part_sources(shape: Shape, seg: Segmentation) -> np.ndarray:
    """(P,) int64: the source node that made most of each part's faces (0: none)."""
    out = np.zeros(seg.n_parts, dtype=np.int64)
    for p in seg.parts:
        src = shape.face_source[p.faces]
        src = src[src > 0]
        if len(src):
            values, counts = np.unique(src, return_counts=True)
            out[p.index] = values[np.argmax(counts)]
    return out


@dataclass
class SourceIndex:
    """Nearest-point lookups in canonical space over the faces of one source node on one part:
    ``index`` over those faces (their referenced vertices only), ``faces (j,)`` their indices among
    the part's own faces (``hit.faces`` of :attr:`index` -> part-local faces)."""

    index: SurfaceIndex
    faces: np.ndarray

    def query(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Part-local faces (k,) and barycentrics (k, 3) of the points nearest ``points`` (k, 3)."""
        hit = self.index.query(points)
        return self.faces[hit.faces], hit.bary


def source_index(canonical: np.ndarray, faces: np.ndarray, face_source: np.ndarray, key: int) -> SourceIndex | None:
    """A :class:`SourceIndex` over the faces of ``faces`` (part-local (j, 3)) whose source is ``key``
    and whose corners all have finite canonical coordinates (``canonical`` (n_local, 3)); None when
    there are none."""
    ok = (face_source == key) & np.isfinite(canonical[faces]).all(axis=(1, 2))
    sub = np.flatnonzero(ok)
    if not len(sub):
        return None
    used, local = np.unique(faces[sub], return_inverse=True)
    return SourceIndex(SurfaceIndex(canonical[used], local.reshape(-1, 3)), sub)


# ---------------------------------------------------------------------------------- tracked points
@dataclass
class TrackedPoints:
    """Points on the template tracked across a family.

    Attributes:
        tracker: one of :data:`TRACKERS`.
        part, group: (k,) int64 template part and group of each point.
        face: (k,) int64 template face; bary: (k, 3) float64 barycentrics on it.
        canonical: (k, 3) canonical coordinates (``canonical`` tracker), else None.
        vertex: (k,) int64 template vertex (``vertex-index`` tracker), else None.
        n_vertices: the template's vertex count (what vertex-index truth requires of every shape).
    """

    tracker: str
    part: np.ndarray
    group: np.ndarray
    face: np.ndarray
    bary: np.ndarray
    canonical: np.ndarray | None = None
    vertex: np.ndarray | None = None
    n_vertices: int = 0

    def __len__(self) -> int:
        return len(self.face)


def tracked_points(template: Shape, grouping: Grouping, tracker: str, n: int = 5000, seed: int = 0) -> TrackedPoints:
    """The tracked template points of a tracker.

    ``canonical``: ``n`` area-uniform samples of the template's non-degenerate parts (the template
    needs canonical coordinates); ``vertex-index``: every vertex of a non-degenerate part; ``cage``:
    ``n`` samples of the non-degenerate group representatives (the parts the cage pairs cover).
    """
    if tracker not in TRACKERS:
        raise ValueError(f"tracker must be one of {', '.join(TRACKERS)}, got {tracker!r}")
    if n < 1:
        raise ValueError(f"need n >= 1 tracked points, got {n}")
    seg = grouping.segmentation
    if tracker == "cage":
        parts = [g.representative for g in grouping.groups if not g.degenerate]
    else:
        parts = [p.index for p in seg.parts if not p.degenerate]
    if not parts:
        raise ValueError("the template has no non-degenerate part to track")
    face_ok = np.zeros(template.n_faces, dtype=bool)
    face_ok[np.concatenate([seg.parts[p].faces for p in parts])] = True
    if tracker == "vertex-index":
        verts = np.concatenate([seg.parts[p].vertices for p in parts])
        face, corner = incident_faces(template.faces, template.n_vertices, face_ok)
        face, bary = face[verts], _one_hot(corner[verts])
        canonical, vertex = None, verts
    else:
        faces = np.flatnonzero(face_ok)
        _, local, bary = sample_surface(template.vertices, template.faces[faces], n, seed=seed)
        face = faces[local]
        canonical, vertex = None, None
        if tracker == "canonical":
            if template.canonical is None:
                raise ValueError("the canonical tracker needs a template with canonical coordinates (a built-in model)")
            canonical = interpolate(template.canonical, template.faces, face, bary)
    part = seg.face_part[face]
    return TrackedPoints(tracker, part, grouping.part_group[part], face, bary, canonical, vertex, template.n_vertices)


@dataclass
class Location:
    """Where points lie on a shape: ``face (k,) int64`` (-1: the shape has no counterpart, the
    point is left out for this shape) and ``bary (k, 3) float64``."""

    face: np.ndarray
    bary: np.ndarray

    @staticmethod
    def empty(k: int) -> "Location":
        return Location(np.full(k, -1, dtype=np.int64), np.zeros((k, 3)))


def match_parts_by_label(template: Shape, tseg: Segmentation, shape: Shape, seg: Segmentation) -> dict[int, int]:
    """The ground-truth pairing of template parts with shape parts: same semantic label, then the
    nearest placement in the bounding box (Hungarian assignment per label). Degenerate parts and
    parts without a counterpart stay unpaired. Both shapes need labels (built-in models).

    Returns ``{template part: shape part}``.
    """
    if by_source(template) and by_source(shape):  # a .blend model's: by the node that made each part
        tkeys, skeys = part_sources(template, tseg), part_sources(shape, seg)
    elif template.labels is None or shape.labels is None:
        raise ValueError("pairing parts by label needs shapes with semantic labels (built-in models)")
    else:
        tkeys = np.array([p.label for p in tseg.parts], dtype=object)
        skeys = np.array([p.label for p in seg.parts], dtype=object)
    out: dict[int, int] = {}
    labels = sorted({tkeys[p.index] for p in tseg.parts if not p.degenerate and (tkeys[p.index] or not by_source(template))})
    for label in labels:
        tp = [p.index for p in tseg.parts if tkeys[p.index] == label and not p.degenerate]
        sp = [p.index for p in seg.parts if skeys[p.index] == label and not p.degenerate]
        if not tp or not sp:
            continue
        tc, te = _placement(template, tseg, tp)
        sc, se = _placement(shape, seg, sp)
        loge = np.abs(np.log(np.maximum(te[:, None], 1e-6) / np.maximum(se[None], 1e-6))).mean(axis=2)
        cost = np.linalg.norm(tc[:, None] - sc[None], axis=2) + loge
        rows, cols = linear_sum_assignment(cost)
        out.update({tp[r]: sp[c] for r, c in zip(rows, cols)})
    return out


def locate_canonical(tracked: TrackedPoints, template: Shape, tseg: Segmentation, shape: Shape, seg: Segmentation) -> Location:
    """Ground-truth location of canonically tracked points on a built-in model's shape: the paired
    part (:func:`match_parts_by_label`), then the point with the same canonical coordinates on it."""
    if tracked.canonical is None:
        raise ValueError("locate_canonical needs points of the canonical tracker")
    if shape.canonical is None:
        raise ValueError("the shape has no canonical coordinates")
    loc = Location.empty(len(tracked))
    keyed = by_source(template) and by_source(shape)
    for tpart, spart in match_parts_by_label(template, tseg, shape, seg).items():
        sel = np.flatnonzero(tracked.part == tpart)
        if not len(sel):
            continue
        part = seg.parts[spart]
        _, f = part_mesh(shape, part)
        if not keyed:
            hit = SurfaceIndex(shape.canonical[part.vertices], f).query(tracked.canonical[sel])
            loc.face[sel], loc.bary[sel] = part.faces[hit.faces], hit.bary
            continue
        # Among the faces of the same source node only; points without one stay unlocated.
        keys = template.face_source[tracked.face[sel]]
        finite = np.isfinite(tracked.canonical[sel]).all(axis=1)
        for key in np.unique(keys[(keys > 0) & finite]):
            idx = source_index(shape.canonical[part.vertices], f, shape.face_source[part.faces], int(key))
            if idx is None:
                continue
            sub = sel[(keys == key) & finite]
            faces, bary = idx.query(tracked.canonical[sub])
            loc.face[sub], loc.bary[sub] = part.faces[faces], bary
    return loc


def check_vertex_index(shape: Shape, n_vertices: int, name: str = "shape") -> None:
    """``ValueError`` unless ``shape`` has ``n_vertices`` vertices (vertex-index truth)."""
    if shape.n_vertices != n_vertices:
        raise ValueError(f"vertex-index truth needs every sample to have the template's {n_vertices} vertices; {name} has {shape.n_vertices}")


def locate_vertex_index(tracked: TrackedPoints, shape: Shape, seg: Segmentation) -> Location:
    """Vertex-index truth: template vertex *i* is the shape's vertex *i* (located on a face of a
    non-degenerate part that uses it; vertices of degenerate shape parts have no counterpart)."""
    if tracked.vertex is None:
        raise ValueError("locate_vertex_index needs points of the vertex-index tracker")
    check_vertex_index(shape, tracked.n_vertices)
    face, corner = incident_faces(shape.faces, shape.n_vertices, _face_ok(seg))
    return Location(face[tracked.vertex], _one_hot(corner[tracked.vertex]))


def locate_by_map(tracked: TrackedPoints, template: Shape, shape: Shape, seg: Segmentation, assignment, assets, mapper, seed: int | dict[int, int] = 0) -> Location:
    """Locate tracked points of group representatives through a correspondence map (the cage
    tracker): per group, the shape part standing for the representative
    (:func:`proctex.transfer.assign.choose_part`) is mapped into the representative's normalised frame by
    ``mapper`` (:class:`proctex.transfer.mappers.Mapper`) and the map is inverted exactly: the closest
    point of the mapped part mesh gives the face and barycentrics of the shape point. ``seed``: the
    mapper's seed, or one per group (the cage tracker solves each pair with the build's seed)."""
    from proctex.transfer.assign import choose_part, representative_part

    loc = Location.empty(len(tracked))
    points = interpolate(template.vertices, template.faces, tracked.face, tracked.bary)
    for g in np.unique(tracked.group):
        a = choose_part(assignment, int(g))
        if a is None:
            continue
        ga = assets.groups[int(g)]
        sel = np.flatnonzero((tracked.group == g) & (tracked.part == ga.rep))
        if not len(sel):
            continue
        part = seg.parts[a.part]
        vn, f = representative_part(*part_mesh(shape, part), a)
        pair_seed = seed.get(int(g), 0) if isinstance(seed, dict) else seed
        mapped = np.asarray(mapper.map(int(g), vn, f, vn, seed=pair_seed), dtype=np.float64)
        hit = SurfaceIndex(mapped, f).query((points[sel] - ga.center) / ga.radius)
        loc.face[sel], loc.bary[sel] = part.faces[hit.faces], hit.bary
    return loc


# ---------------------------------------------------------------------------------------- colours
def colours_at(loc: Location, corner_uv: np.ndarray, face_group: np.ndarray, textures: Sequence[np.ndarray]) -> np.ndarray:
    """Colours (k, 3) float64 in [0, 1] that a textured shape shows at located points.

    ``corner_uv (m, 3, 2)``, ``face_group (m,)`` and per group ``textures (H, W, 3)``: the shape's
    texturing (a transfer's real-time UVs into the template textures, or a bake). Rows are NaN
    where the point has no counterpart on the shape, +inf where the face has no texture (counted
    by :func:`tracked_variance` as the colour farthest from the template's).
    """
    out = np.full((len(loc.face), 3), np.nan)
    valid = np.flatnonzero(loc.face >= 0)
    if not len(valid):
        return out
    faces = loc.face[valid]
    fg = np.asarray(face_group)[faces]
    uv = np.einsum("ij,ijk->ik", loc.bary[valid], np.asarray(corner_uv)[faces])
    for gi in np.unique(fg):
        sel = fg == gi
        if 0 <= gi < len(textures):
            out[valid[sel]] = sample_texture(textures[gi], uv[sel])[:, :3]
        else:
            out[valid[sel]] = np.inf
    return out


@dataclass
class TrackedVariance:
    """Tracked-point texture variance: ``value`` (mean over points and RGB of the per-point
    standard deviation over shapes, the template included), ``per_group``, ``points`` measured
    (seen on the template and at least one shape), ``shapes`` (template excluded), ``missing``
    (share of (shape, point) readings on untextured faces, counted) and the ``tracker``."""

    value: float
    per_group: dict[int, float]
    points: int
    shapes: int
    missing: float
    tracker: str

    def to_dict(self) -> dict[str, Any]:
        return {"value": self.value, "per_group": {str(k): v for k, v in self.per_group.items()}, "points": self.points, "shapes": self.shapes, "missing": self.missing, "tracker": self.tracker}


def tracked_variance(template_colours: np.ndarray, shape_colours: Sequence[np.ndarray], groups: np.ndarray, tracker: str) -> TrackedVariance:
    """Combine the template's colours (k, 3) and each shape's (:func:`colours_at`) at the tracked
    points (``groups (k,)`` their template groups). Untextured readings (+inf) count as the colour
    farthest from the template's (per channel 0 or 1); NaN readings (no counterpart) are left out."""
    c0 = np.asarray(template_colours, dtype=np.float64)
    if c0.ndim != 2 or c0.shape[1] != 3 or not np.isfinite(c0).all():
        raise ValueError(f"template colours must be a finite (k, 3) array, got {c0.shape}")
    if not shape_colours:
        raise ValueError("tracked-point variance needs at least one shape besides the template")
    far = np.where(c0 < 0.5, 1.0, 0.0)
    stack = [c0]
    n_missing = n_read = 0
    for c in shape_colours:
        c = np.array(c, dtype=np.float64)
        if c.shape != c0.shape:
            raise ValueError(f"shape colours must be {c0.shape}, got {c.shape}")
        miss = np.isinf(c).any(axis=1)
        n_missing += int(miss.sum())
        n_read += int((~np.isnan(c).any(axis=1)).sum())
        c[miss] = far[miss]
        stack.append(c)
    s = np.stack(stack)  # (shapes + 1, k, 3)
    count = (~np.isnan(s[:, :, 0])).sum(axis=0)
    keep = count >= 2
    if not keep.any():
        raise ValueError("no tracked point was found on any shape")
    mean = np.nanmean(s[:, keep], axis=0)
    std = np.sqrt(np.nanmean((s[:, keep] - mean) ** 2, axis=0)).mean(axis=1)  # (kept,)
    g = np.asarray(groups)[keep]
    per_group = {int(x): float(std[g == x].mean()) for x in np.unique(g)}
    return TrackedVariance(float(std.mean()), per_group, int(keep.sum()), len(shape_colours), n_missing / max(n_read, 1), tracker)


# ------------------------------------------------------------------------------ correspondence error
@dataclass
class TemplateTruth:
    """What the ground truth says about the template, per kind.

    ``canonical``: ``label_groups`` {label: template groups holding parts of that label} and per
    group an index over its representative's canonical mesh (``rep_canonical``); keyed by source
    node for a ``.blend`` template (``sources``): ``label_groups`` {node: groups whose
    representative has faces of it} and ``rep_canonical`` {(group, node): :class:`SourceIndex`}. ``vertex-index``:
    ``vertex_group (n,)`` each template vertex's group (-1: none) and ``vertex_point (n, 3)`` the
    vertex carried by its member map into the group representative's normalised frame.
    """

    kind: str
    label_groups: dict[Any, set[int]] = field(default_factory=dict)
    rep_canonical: dict[Any, Any] = field(default_factory=dict)
    vertex_group: np.ndarray | None = None
    vertex_point: np.ndarray | None = None
    n_vertices: int = 0
    sources: bool = False


def template_truth(template: Shape, grouping: Grouping, assets, kind: str) -> TemplateTruth:
    """:class:`TemplateTruth` of ``kind`` ("canonical" or "vertex-index") from the template, its
    grouping and its transfer assets (:class:`proctex.transfer.assets.TemplateAssets`)."""
    seg = grouping.segmentation
    if kind == "canonical":
        if template.canonical is not None and by_source(template):
            truth = TemplateTruth(kind, n_vertices=template.n_vertices, sources=True)
            for g in grouping.groups:
                if g.degenerate:
                    continue
                rep = seg.parts[g.representative]
                _, f = part_mesh(template, rep)
                src = template.face_source[rep.faces]
                for key in np.unique(src[src > 0]).tolist():
                    idx = source_index(template.canonical[rep.vertices], f, src, key)
                    if idx is not None:
                        truth.label_groups.setdefault(key, set()).add(g.index)
                        truth.rep_canonical[(g.index, key)] = idx
            return truth
        if template.canonical is None or template.labels is None:
            raise ValueError("canonical truth needs a template with canonical coordinates: a built-in model, or a .blend model whose node tree was read")
        truth = TemplateTruth(kind, n_vertices=template.n_vertices)
        for g in grouping.groups:
            if g.degenerate:
                continue
            for m in g.members:
                truth.label_groups.setdefault(seg.parts[m].label, set()).add(g.index)
            rep = seg.parts[g.representative]
            _, f = part_mesh(template, rep)
            truth.rep_canonical[g.index] = SurfaceIndex(template.canonical[rep.vertices], f)
        return truth
    if kind == "vertex-index":
        group = np.full(template.n_vertices, -1, dtype=np.int64)
        point = np.zeros((template.n_vertices, 3))
        for g in grouping.groups:
            if g.degenerate:
                continue
            ga = assets.groups[g.index]
            for m in g.maps:
                verts = seg.parts[m.part].vertices
                group[verts] = g.index
                if m.method == "deformed":  # its vertex i is the representative's vertex i (R, t only approximate it)
                    point[verts] = (template.vertices[seg.parts[g.representative].vertices] - ga.center) / ga.radius
                else:
                    point[verts] = (template.vertices[verts] @ np.asarray(m.R).T + m.t - ga.center) / ga.radius
        return TemplateTruth(kind, vertex_group=group, vertex_point=point, n_vertices=template.n_vertices)
    raise ValueError(f"ground truth is canonical or vertex-index, got {kind!r}")


@dataclass
class Samples:
    """Shape points with a known truth: ``part``, ``face`` (k,) int64, ``bary (k, 3)``, and
    ``canonical (k, 3)`` or ``vertex (k,)`` by the truth's kind."""

    part: np.ndarray
    face: np.ndarray
    bary: np.ndarray
    canonical: np.ndarray | None = None
    vertex: np.ndarray | None = None


def truth_samples(shape: Shape, seg: Segmentation, kind: str, n: int = 5000, seed: int = 0) -> Samples:
    """Points of a shape's non-degenerate parts to measure errors at: ``n`` area-uniform samples
    with canonical coordinates (``canonical``), or every vertex (``vertex-index``)."""
    ok = _face_ok(seg)
    if not ok.any():
        raise ValueError("the shape has no non-degenerate part")
    if kind == "vertex-index":
        face, corner = incident_faces(shape.faces, shape.n_vertices, ok)
        verts = np.flatnonzero(face >= 0)
        return Samples(seg.face_part[face[verts]], face[verts], _one_hot(corner[verts]), vertex=verts)
    if kind != "canonical":
        raise ValueError(f"ground truth is canonical or vertex-index, got {kind!r}")
    if shape.canonical is None:
        raise ValueError("canonical truth needs a shape with canonical coordinates")
    faces = np.flatnonzero(ok)
    _, local, bary = sample_surface(shape.vertices, shape.faces[faces], n, seed=seed)
    face = faces[local]
    return Samples(seg.face_part[face], face, bary, canonical=interpolate(shape.canonical, shape.faces, face, bary))


def _mapped_points(shape: Shape, seg: Segmentation, result, assets, part: int, face: np.ndarray, bary: np.ndarray, group: int):
    """A transfer's template points (k, 3) for shape points on ``part`` (global faces and
    barycentrics): its mapped vertices interpolated, in group ``group``'s representative's
    normalised frame, projected onto the representative on the side its face is on (as
    :func:`proctex.transfer.uvlookup.part_uvs` reads the texture); and the representative's faces (k,) they
    land on."""
    from proctex.transfer.assign import representative_part
    from proctex.transfer.uvlookup import side_normals

    p = seg.parts[part]
    ga = assets.groups[group]
    local = np.searchsorted(p.vertices, shape.faces[face])
    mapped = (np.asarray(result.points[part]) - ga.center) / ga.radius
    pts = np.einsum("kj,kjd->kd", bary, mapped[local])
    # Projected on the side the point's face is on, as the transfer reads the texture (part_uvs).
    a = next((x for x in result.assignment if x.part == part), None)
    src, wound = representative_part(shape.vertices[p.vertices], local, a) if a is not None else (mapped, local)
    hit = ga.index.query_facing(pts, side_normals(src, wound), k=16)
    return hit.points, hit.faces


def _facing_away(ga, faces: np.ndarray, reference_faces: np.ndarray) -> np.ndarray:
    """(k,) float: 1 where representative face ``faces[i]`` faces away from ``reference_faces[i]``
    (the other side of a thin wall), else 0; ``ga``: the group's assets (its index holds the face
    normals)."""
    n = ga.index.normals
    return (np.einsum("kd,kd->k", n[faces], n[reference_faces]) < 0).astype(np.float64)


def gt_errors(shape: Shape, seg: Segmentation, samples: Samples, result, assets, truth: TemplateTruth, flips: bool = False):
    """Ground-truth errors (k,) of a transfer (:class:`proctex.transfer.apply.TransferResult`) at
    ``samples``, in the normalised frame of the representative the method chose, and the group
    (k,) each point was measured in (-1: failed or no truth). With ``flips``, also (k,) float:
    1 where the point landed on a template face facing away from its true face (the other side of
    a thin wall: a mug's inside for its outside), 0 where not, NaN where not measured.

    A point fails (:data:`FAIL_ERROR`) when the method left its part untextured or mapped it into a
    group the truth does not allow (canonical: no template part of that label in the group;
    vertex-index: the true template vertex lies in another group). Points whose truth has no
    counterpart on the template (a part the template lacks, a vertex of a degenerate template
    part) are NaN: nothing is right or wrong there.
    """
    labels = np.array([p.label for p in seg.parts], dtype=object)
    keys = None
    if truth.kind == "vertex-index":
        check_vertex_index(shape, truth.n_vertices)
        has_truth = truth.vertex_group[samples.vertex] >= 0
    elif truth.sources:
        if not by_source(shape):
            raise ValueError("the template's truth is keyed by source node, the shape has none")
        keys = shape.face_source[samples.face]
        has_truth = np.isin(keys, list(truth.label_groups)) & np.isfinite(samples.canonical).all(axis=1)
    else:
        has_truth = np.isin(labels[samples.part], list(truth.label_groups))
    errors = np.where(has_truth, FAIL_ERROR, np.nan)
    flipped = np.full(len(samples.face), np.nan)
    groups = np.full(len(samples.face), -1, dtype=np.int64)
    method_group = {a.part: a.group for a in result.assignment}
    for part in np.unique(samples.part[has_truth]):
        sel = np.flatnonzero((samples.part == part) & has_truth)
        g = method_group.get(int(part), -1)
        if g < 0 or int(part) not in result.points:
            continue
        if truth.sources:
            # Only among the representative's faces of the point's own source node: a point whose
            # node the method's group lacks stays failed.
            sel = np.concatenate([sel[keys[sel] == k] for k in np.unique(keys[sel]) if (g, int(k)) in truth.rep_canonical] or [sel[:0]])
            if not len(sel):
                continue
            ga = assets.groups[g]
            true_faces = np.empty(len(sel), dtype=np.int64)
            bary = np.empty((len(sel), 3))
            for k in np.unique(keys[sel]):
                at = keys[sel] == k
                true_faces[at], bary[at] = truth.rep_canonical[(g, int(k))].query(samples.canonical[sel[at]])
            true = interpolate(ga.vertices, ga.faces, true_faces, bary)
        elif truth.kind == "canonical":
            if g not in truth.label_groups.get(seg.parts[int(part)].label, ()):
                continue
            hit = truth.rep_canonical[g].query(samples.canonical[sel])
            ga = assets.groups[g]
            true, true_faces = interpolate(ga.vertices, ga.faces, hit.faces, hit.bary), hit.faces
        else:
            sel = sel[truth.vertex_group[samples.vertex[sel]] == g]
            if not len(sel):
                continue
            true = truth.vertex_point[samples.vertex[sel]]
            true_faces = assets.groups[g].index.query(true).faces if flips else None
        pred, pred_faces = _mapped_points(shape, seg, result, assets, int(part), samples.face[sel], samples.bary[sel], g)
        errors[sel] = np.linalg.norm(pred - true, axis=1)
        groups[sel] = g
        if flips:
            flipped[sel] = _facing_away(assets.groups[g], pred_faces, true_faces)
    return (errors, groups, flipped) if flips else (errors, groups)


def pgt_errors(shape: Shape, seg: Segmentation, result, assets, pairs: Sequence[dict[str, Any]], flips: bool = False):
    """Pseudo-ground-truth errors of a transfer against the stored cage pairs of this shape.

    ``pairs``: per pair ``{"group", "part", "src" (n, 3), "dst" (n, 3)}`` (source samples in the
    representative's normalised frame, as :func:`proctex.transfer.assign.representative_frame` puts the
    part, and their cage template points). Returns ``(errors (N,), groups (N,), per-pair means)``;
    a pair whose part the method dropped or put in another group fails every point. With ``flips``,
    also (N,) float: 1 where the point landed on a template face facing away from the face its cage
    point lies on (the other side of a thin wall, measured without ground truth), 0 where not, NaN
    on failed pairs.
    """
    from proctex.transfer.assign import representative_frame

    by_part = {a.part: a for a in result.assignment}
    errs, grps, means, flipped = [], [], [], []
    for pr in pairs:
        g, part = int(pr["group"]), int(pr["part"])
        src, dst = np.asarray(pr["src"], dtype=np.float64), np.asarray(pr["dst"], dtype=np.float64)
        a = by_part.get(part)
        fl = np.full(len(src), np.nan)
        if a is None or a.group != g or part not in result.points or part >= len(seg.parts):
            e = np.full(len(src), FAIL_ERROR)
        else:
            p = seg.parts[part]
            v, f = part_mesh(shape, p)
            hit = SurfaceIndex(representative_frame(v, a), f).query(src)
            pred, pred_faces = _mapped_points(shape, seg, result, assets, part, p.faces[hit.faces], hit.bary, g)
            e = np.linalg.norm(pred - dst, axis=1)
            if flips:
                fl = _facing_away(assets.groups[g], pred_faces, assets.groups[g].index.query(dst).faces)
        errs.append(e)
        grps.append(np.full(len(e), g, dtype=np.int64))
        means.append(float(e.mean()))
        flipped.append(fl)
    if not errs:
        return (np.zeros(0), np.zeros(0, dtype=np.int64), []) + ((np.zeros(0),) if flips else ())
    out = (np.concatenate(errs), np.concatenate(grps), means)
    return out + (np.concatenate(flipped),) if flips else out


def error_summary(errors: np.ndarray) -> dict[str, Any]:
    """``{"mean", "p95", "p99", "max", "points", "failed"}`` of point errors (``max``: the largest
    error over all points; ``failed``: share of points at :data:`FAIL_ERROR`; NaN points, without
    a truth, are left out); {} when none is left."""
    e = np.asarray(errors, dtype=np.float64)
    e = e[~np.isnan(e)]
    if not len(e):
        return {}
    return {"mean": float(e.mean()), "p95": float(np.percentile(e, 95)), "p99": float(np.percentile(e, 99)), "max": float(e.max()), "points": int(len(e)), "failed": float(np.mean(e >= FAIL_ERROR))}
