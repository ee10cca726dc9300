"""Dense correspondence from a shape's part to the template's part, and over whole shapes.

One interface, three methods (:data:`METHODS`):

- ``"cage"``: similarity pre-alignment, then the per-pair cage deformation of :mod:`proctex.correspond.cage`;
  the deformed samples are projected onto the template surface (faces with agreeing normals).
- ``"nearest"``: the same similarity pre-alignment, then the nearest template surface point (what
  a plain "data transfer" tool gives).
- ``"cpd"``: the same pre-alignment, then non-rigid Coherent Point Drift (:mod:`proctex.correspond.cpd`) and
  the nearest template surface point.

Pre-alignment: both parts in their normalised frames (bounding-box centre, L∞ radius; docs/correspondence.md),
then point-to-surface ICP with a uniform scale (Umeyama on the ICP matches) from the identity
(families keep their orientation), or the per-axis scale of the two bounding boxes ("box"), or
whichever of the two leaves the smaller symmetric point-to-surface distance ("auto", the cage's
default). Procedural parts are mostly stretched versions of each other, which the box map takes
exactly and a similarity cannot: the nearest point after the box start alone has ground-truth
error 0.0000-0.005 on the chair and table parts (up to 0.16 after ICP) and 0.015-0.020 on three
vases, where the old cage ended at 0.044-0.067 (``tests/bench/bench_correspond.py --tessellation adaptive``). A
sheared or tapered part is an affine image, not a per-axis stretch: "auto" refines the box map by
facet-matched affine ICP (:func:`proctex.geometry.align.affine_icp_to_surface`) and keeps the
refinement where it fits at least as well (issue 32: cage GT mean over 8 built-ins and the sofa,
fork 0.0044 -> 0.0027, mushroom 0.0092 -> 0.0035, stair 0.0212 -> 0.0177, no family worse by
more than 0.0002). The baselines keep ICP (a plain data transfer). The transform (a general
linear map after "affine") is kept in the result.

Tube-like pairs (coils, rails) may instead be mapped along and around the parts through their
sweep charts (``CageConfig.sweep``, :mod:`proctex.correspond.sweep`).

:func:`correspond_shapes` matches part groups (:func:`proctex.geometry.matching.match_groups`) and solves every
matched group pair between the shape member that lies where the template's representative lies and
that representative; with canonical coordinates on both shapes it also reports the ground-truth
error (:mod:`proctex.texture.metrics`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from proctex.geometry.align import affine_icp_to_surface, apply, chamfer, icp_to_surface
from proctex.geometry.matching import GroupMatch, match_groups
from proctex.geometry.parts import Grouping, PartGroup, analyse, part_mesh, symmetry_planes
from proctex.geometry.shape import Shape
from proctex.geometry.surface import SurfaceIndex, face_normals, normalised_frame, sample_surface, triangle_areas, vertex_normals
from proctex.geometry.surface import interpolate
from .cage import CageConfig, CageResult, solve_cage
from .cage_batch import CageProblem, solve_cages
from .cpd import cpd_nonrigid
from .metrics import GTError, gt_correspondence_error

METHODS = ("cage", "nearest", "cpd")


@dataclass
class Similarity:
    """``x -> s R x + t`` (world source -> world template); ``R`` is a rotation after ICP and a
    diagonal per-axis scale after the "box" pre-alignment."""

    s: float
    R: np.ndarray
    t: np.ndarray

    def apply(self, points: np.ndarray) -> np.ndarray:
        return apply(points, self.R, self.t, self.s)

    def to_dict(self) -> dict[str, Any]:
        return {"s": self.s, "R": self.R.tolist(), "t": self.t.tolist()}


@dataclass
class PartCorrespondence:
    """Where each source sample lands on the template part.

    Attributes:
        method: "cage", "nearest" or "cpd".
        source_points: (n, 3) source samples (world); source_faces (n,) int64 and source_bary (n, 3)
            locate them on the source part mesh.
        faces: (n,) int64 template part faces; bary: (n, 3); points: (n, 3) template points (world).
        residual: mean distance from the deformed (or aligned) source samples to the template
            surface before projection, in the template part's normalised frame.
        chamfer: symmetric mean nearest-neighbour distance between deformed samples and template
            samples (normalised frame).
        converged, iterations: of the optimisation (the baselines report their own loop).
        seconds: wall time of the solve (pre-alignment included).
        alignment: the similarity pre-alignment.
        oriented: share of samples projected onto a face whose normal agrees with the sample's
            (deformed normal for the cage, pre-aligned normal for the baselines).
        details: method-specific figures (loss terms, ICP error, CPD variance).
    """

    method: str
    source_points: np.ndarray
    source_faces: np.ndarray
    source_bary: np.ndarray
    faces: np.ndarray
    bary: np.ndarray
    points: np.ndarray
    residual: float
    chamfer: float
    converged: bool
    iterations: int
    seconds: float
    alignment: Similarity
    oriented: float
    details: dict[str, Any] = field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        return {
            "method": self.method,
            "points": int(len(self.points)),
            "residual": self.residual,
            "chamfer": self.chamfer,
            "converged": self.converged,
            "iterations": self.iterations,
            "seconds": self.seconds,
            "oriented": self.oriented,
            "alignment": self.alignment.to_dict(),
            **{k: v for k, v in self.details.items() if isinstance(v, (int, float, str, bool))},
        }


def check_part(vertices: np.ndarray, faces: np.ndarray, what: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Validate a part mesh; returns ``(vertices (j, 3) float64, faces (k, 3) int64, centre, radius)``
    with the part's normalised frame."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"{what}: expected vertices (j, 3) and faces (k, 3), got {v.shape} and {f.shape}")
    if len(f) == 0 or len(v) == 0:
        raise ValueError(f"{what}: the part is empty (no faces)")
    if f.min() < 0 or f.max() >= len(v):
        raise ValueError(f"{what}: face indices outside [0, {len(v)})")
    if not np.all(np.isfinite(v[np.unique(f)])):
        raise ValueError(f"{what}: vertices contain NaN or inf")
    area = triangle_areas(v, f).sum()
    center, radius = normalised_frame(v[np.unique(f)])
    if not area > 1e-12 * max(radius, 1e-300) ** 2 or radius <= 0:
        raise ValueError(f"{what}: the part is degenerate (zero surface area); it has no surface to texture")
    return v, f, center, radius


@dataclass
class _Prepared:
    src_v: np.ndarray
    src_f: np.ndarray
    src_center: np.ndarray
    src_radius: float
    tpl_center: np.ndarray
    tpl_radius: float
    samples: np.ndarray  # (n, 3) world source samples
    sample_faces: np.ndarray
    sample_bary: np.ndarray
    index: SurfaceIndex  # template, normalised frame (its vertices, faces and face normals)
    R: np.ndarray  # pre-alignment in normalised frames
    t: np.ndarray
    s: float
    icp_error: float

    def aligned(self, world_points: np.ndarray) -> np.ndarray:
        """Source world points -> template normalised frame (after pre-alignment)."""
        return apply((world_points - self.src_center) / self.src_radius, self.R, self.t, self.s)

    def to_world(self, normalised: np.ndarray) -> np.ndarray:
        return normalised * self.tpl_radius + self.tpl_center

    def similarity(self) -> Similarity:
        s = self.s * self.tpl_radius / self.src_radius
        t = self.tpl_center + self.tpl_radius * self.t - s * self.R @ self.src_center
        return Similarity(float(s), self.R.copy(), t)


def box_scale(src: np.ndarray, tpl: np.ndarray, min_extent: float = 0.05) -> np.ndarray:
    """Per-axis scale (3,) taking the bounding box of ``src (j, 3)`` onto that of ``tpl (k, 3)``,
    both in their normalised frames (boxes centred on the origin). An axis on which either part is
    flat (extent below ``min_extent``, radius 1) keeps scale 1."""
    es, et = np.ptp(src, axis=0), np.ptp(tpl, axis=0)
    ok = (es > min_extent) & (et > min_extent)
    return np.where(ok, et / np.where(ok, es, 1.0), 1.0)


#: A source part is taken as wound inside out relative to the template when its sample normals,
#: box-mapped, agree with their nearest template faces' this much or less on average (-1: all
#: opposed, 1: all agreeing; an outward part scores near 1, a part turned by the box map near 0).
INSIDE_OUT = -0.25


def inside_out(normals: np.ndarray, k: np.ndarray, template_normals: np.ndarray) -> bool:
    """Whether a source part is wound inside out relative to the template (a mirrored copy brought
    over by a reflection, an export whose faces wind inward): the face ``normals (m, 3)`` of its
    samples, carried by the box map's per-axis scale ``k (3,)`` (:func:`box_scale`), face away on
    average (:data:`INSIDE_OUT`) from ``template_normals (m, 3)``, those of the template faces
    nearest the box-mapped samples. The cage's normal terms, the facet-matched affine start and
    the final side-aware projection all read the source's normals, so such a part would be mapped
    onto the other side of every wall."""
    nrm = normals / k  # normals map by the inverse transpose of diag(k)
    nrm = nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
    return bool(len(nrm)) and float(np.einsum("kd,kd->k", template_normals, nrm).mean()) <= INSIDE_OUT


def prepare(src_v: np.ndarray, src_f: np.ndarray, tpl_v: np.ndarray, tpl_f: np.ndarray, n_points: int, seed: int, icp_points: int = 500, prealign: str = "icp") -> _Prepared:
    """Validate, sample the source, and pre-align it to the template.

    ``prealign``: "icp" (similarity ICP from the identity of the normalised frames), "box" (the
    per-axis scale of :func:`box_scale`, no rotation), "affine" (the box map refined by
    facet-matched affine ICP) or "auto" (the box map, replaced by its affine refinement where that
    fits at least as well, or ICP: whichever leaves the smaller symmetric point-to-surface distance
    to the template, on ``icp_points`` samples each).
    """
    from .cage import PREALIGNS

    if prealign not in PREALIGNS:
        raise ValueError(f"prealign must be one of {', '.join(PREALIGNS)}, got {prealign!r}")
    src_v, src_f, sc, sr = check_part(src_v, src_f, "source part")
    tpl_v, tpl_f, tc, tr = check_part(tpl_v, tpl_f, "template part")
    if int(n_points) < 1:
        raise ValueError(f"n_points must be >= 1, got {n_points}")
    rng = np.random.default_rng(seed)
    samples, sf, sb = sample_surface(src_v, src_f, int(n_points), seed=rng)
    index = SurfaceIndex((tpl_v - tc) / tr, tpl_f)
    pick = rng.choice(len(samples), size=min(icp_points, len(samples)), replace=False)
    sub = (samples[pick] - sc) / sr
    # The box map, queried once: the orientation test's reference and the box start.
    k = box_scale((src_v[np.unique(src_f)] - sc) / sr, index.vertices[np.unique(tpl_f)])
    box_hit = index.query(sub * k, exact=False)
    if inside_out(face_normals(src_v, src_f)[sf[pick]], k, index.normals[box_hit.faces]):
        src_f = src_f[:, ::-1].copy()  # same faces, same samples: only the normals turn outward
    tpl_s = sample_surface(index.vertices, index.faces, len(sub), seed=rng)[0] if prealign in ("affine", "auto") else None
    src_norm = (src_v - sc) / sr

    def fit_of(R: np.ndarray, t: np.ndarray, s: float) -> float:
        """Symmetric point-to-surface distance of an alignment: source samples to the template's
        surface and template samples to the moved source's (exact; point-to-point Chamfer on a few
        hundred samples cannot tell a 1e-6 fit from a 4e-4 one)."""
        if tpl_s is None:
            return 0.0
        there = index.query(apply(sub, R, t, s)).distance.mean()
        back = SurfaceIndex(apply(src_norm, R, t, s), src_f).query(tpl_s).distance.mean()
        return float(0.5 * (there + back))

    candidates = []  # (R, t, s, error, symmetric surface distance)
    if prealign in ("box", "affine", "auto"):
        candidates.append((np.diag(k), np.zeros(3), 1.0, float(box_hit.distance.mean()), fit_of(np.diag(k), np.zeros(3), 1.0)))
        if prealign in ("affine", "auto"):
            fit = affine_icp_to_surface(sub, face_normals(src_v, src_f)[sf[pick]], index, A0=np.diag(k))
            if fit.accepted:
                c = fit_of(fit.A, fit.t, 1.0)
                # the facet fit replaces the box start only where it fits at least as well
                if prealign == "affine" or c <= candidates[0][4]:
                    candidates[0] = (fit.A, fit.t, 1.0, fit.error, c)
    if prealign in ("icp", "auto"):
        icp = icp_to_surface(sub, index, scale=True, max_iter=100, tol=1e-7, exact=False)
        candidates.append((icp.R, icp.t, icp.s, icp.error, fit_of(icp.R, icp.t, icp.s)))
    candidates.sort(key=lambda c: c[4])  # stable: box first on a tie
    R, t, s, error, _ = candidates[0]
    return _Prepared(src_v, src_f, sc, sr, tc, tr, samples, sf, sb, index, R, t, s, error)


def template_symmetry_axes(vertices: np.ndarray, faces: np.ndarray, tol: float = 0.01, seed: int = 0) -> tuple[int, ...]:
    """Axes ``a`` whose plane ``x[a] = 0`` mirrors a part given in its normalised frame."""
    planes = symmetry_planes(Shape(vertices, faces), tol=tol, seed=seed)
    axes = []
    for p in planes:
        a = int(np.argmax(np.abs(p.normal)))
        if abs(p.normal[a]) > 0.999 and abs(p.offset) < tol:
            axes.append(a)
    return tuple(sorted(set(axes)))


def _finish(
    prep: _Prepared, method: str, moved: np.ndarray, normals: np.ndarray | None, t0: float, converged: bool, iterations: int, template_samples: np.ndarray, details: dict[str, Any]
) -> PartCorrespondence:
    if normals is not None:
        hit, oriented = prep.index.query_oriented(moved, normals)
    else:
        hit = prep.index.query(moved)
        # Baselines do not use normals; report how many matches agree with the aligned source normal.
        aligned_normals = face_normals(prep.src_v, prep.src_f)[prep.sample_faces] @ np.linalg.inv(prep.R)  # normals: inverse transpose
        oriented = np.einsum("kd,kd->k", prep.index.normals[hit.faces], aligned_normals) > 0
    return PartCorrespondence(
        method=method,
        source_points=prep.samples,
        source_faces=prep.sample_faces,
        source_bary=prep.sample_bary,
        faces=hit.faces,
        bary=hit.bary,
        points=prep.to_world(hit.points),
        residual=float(hit.distance.mean()),
        chamfer=chamfer(moved, template_samples),
        converged=bool(converged),
        iterations=int(iterations),
        seconds=time.perf_counter() - t0,
        alignment=prep.similarity(),
        oriented=float(oriented.mean()),
        details={"icp_error": prep.icp_error, **details},
    )


def correspond_parts(
    src_vertices: np.ndarray,
    src_faces: np.ndarray,
    tpl_vertices: np.ndarray,
    tpl_faces: np.ndarray,
    method: str = "cage",
    n_points: int = 2000,
    seed: int = 0,
    cage: CageConfig | None = None,
    cpd_beta: float = 3.0,
    cpd_lambda: float = 8.0,
    cpd_points: int = 600,
    template_points: int = 3000,
    prealign: str | None = None,
    warm: PartCorrespondence | None = None,
) -> PartCorrespondence:
    """Correspondence from ``n_points`` uniform samples of a source part to a template part.

    Args:
        src_vertices, src_faces: (j, 3) float64 / (k, 3) int64 source part mesh.
        tpl_vertices, tpl_faces: template part mesh.
        method: one of :data:`METHODS`.
        cage: settings of the cage solver (method "cage").
        cpd_beta, cpd_lambda, cpd_points: CPD kernel width (normalised units), smoothness and the
            number of source / template points it is fitted on (method "cpd"). The defaults were
            the best of beta in {1, 2, 3} x lambda in {2, 8} on the correspondence benchmark.
        template_points: uniform template samples for the Chamfer terms.
        prealign: "icp", "box", "affine" or "auto" (:func:`prepare`); default: ``cage.prealign`` for the
            cage, "icp" for the baselines (a plain similarity-aligned data transfer).
        warm: the cage correspondence of a neighbouring pair onto the same template part: its cage
            is the solver's warm start (:func:`proctex.correspond.cage.solve_cage`'s ``start``;
            ignored unless it carries a cage).

    Raises:
        ValueError: unknown method, empty / degenerate / non-finite parts.
    """
    if method not in METHODS:
        raise ValueError(f"unknown correspondence method {method!r}; expected one of {', '.join(METHODS)}")
    t0 = time.perf_counter()
    if prealign is None:
        prealign = (cage or CageConfig()).prealign if method == "cage" else "icp"
    prep = prepare(src_vertices, src_faces, tpl_vertices, tpl_faces, n_points, seed, prealign=prealign)
    rng = np.random.default_rng(seed + 1)
    tpl_s, tpl_sf, _ = sample_surface(prep.index.vertices, prep.index.faces, template_points, seed=rng)
    aligned = prep.aligned(prep.samples)
    if method == "nearest":
        return _finish(prep, method, aligned, None, t0, True, 0, tpl_s, {})
    if method == "cpd":
        sub = rng.choice(len(aligned), size=min(cpd_points, len(aligned)), replace=False)
        tsub = rng.choice(len(tpl_s), size=min(cpd_points * 2, len(tpl_s)), replace=False)
        fit = cpd_nonrigid(aligned[sub], tpl_s[tsub], beta=cpd_beta, lam=cpd_lambda, device=(cage.device if cage else "cpu"))
        moved = fit.transform(aligned)
        return _finish(prep, method, moved, None, t0, fit.converged, fit.iterations, tpl_s, {"sigma2": fit.sigma2, "field": fit})
    # cage
    problem = _cage_problem(prep, aligned, tpl_s, tpl_sf, seed)
    tpl_vn = vertex_normals(prep.index.vertices, prep.index.faces)
    axes = template_symmetry_axes(prep.index.vertices, prep.index.faces, seed=seed) if (cage and cage.symmetry) else ()
    start = (warm.details["cage0"], warm.details["cage"]) if warm is not None and "cage" in warm.details else None
    res = solve_cage(
        problem.points, problem.tri_vertices, problem.tri_faces, problem.tri_index, prep.index, tpl_vn, tpl_s, problem.template_sample_normals, cage, symmetry_axes=axes, seed=seed, start=start
    )
    return _cage_finish(prep, cage, res, axes, tpl_s, t0)


def _cage_problem(prep: _Prepared, aligned: np.ndarray, tpl_s: np.ndarray, tpl_sf: np.ndarray, seed: int) -> CageProblem:
    """The cage solver's inputs for a prepared pair: the aligned samples and the source triangles
    they lie on (re-indexed, wound outward after a mirroring alignment), the template samples."""
    used, inverse = np.unique(prep.sample_faces, return_inverse=True)
    tri = prep.src_f[used]
    verts, tri_local = np.unique(tri, return_inverse=True)
    tri_local = tri_local.reshape(-1, 3)
    tv = prep.aligned(prep.src_v[verts])
    if prep.s * np.linalg.det(prep.R) < 0:
        tri_local = tri_local[:, ::-1]
    return CageProblem(aligned, tv, tri_local, inverse.reshape(-1), tpl_s, prep.index.normals[tpl_sf], seed)


def _cage_finish(prep: _Prepared, cage: CageConfig | None, res: CageResult, axes: tuple[int, ...], tpl_s: np.ndarray, t0: float) -> PartCorrespondence:
    """A solved cage pair as a correspondence (or the sweep chart's map where that fits better)."""
    method = "cage"
    sweep = _sweep_candidate(prep, cage, res.points, tpl_s)
    if sweep is not None:
        moved, field = sweep
        return _finish(prep, method, moved, None, t0, True, 0, tpl_s, {"teacher": "sweep", "sweep": field, "turns": field.source.turns, "template_turns": field.template.turns})
    details: dict[str, Any] = {f"loss_{k}": v for k, v in res.terms.items()}
    details["symmetry_axes"] = list(axes)
    details["cage"] = res.cage
    details["cage0"] = res.cage0
    details["cage_faces"] = res.cage_faces
    details["loss"] = res.loss
    details["history"] = res.history
    return _finish(prep, method, res.points, res.normals, t0, res.converged, res.iterations, tpl_s, details)


def correspond_parts_batch(
    sources: Sequence[tuple[np.ndarray, np.ndarray, int]],
    tpl_vertices: np.ndarray,
    tpl_faces: np.ndarray,
    n_points: int = 2000,
    cage: CageConfig | None = None,
    template_points: int = 3000,
    search: str | None = None,
) -> list[PartCorrespondence]:
    """:func:`correspond_parts` with method "cage" for several source parts onto one template part,
    their cage solves batched (:func:`proctex.correspond.cage_batch.solve_cages`): the same
    correspondences, to float rounding, at less cost per pair (with ``search`` "host"; "device",
    the default on CUDA, finds each step's matches on the device by another candidate search).

    Args:
        sources: per pair ``(vertices (j, 3), faces (k, 3), seed)`` of the source part.
        tpl_vertices, tpl_faces, n_points, cage, template_points: as :func:`correspond_parts`.
        search: :func:`proctex.correspond.cage_batch.solve_cages`'s.

    Raises ``ValueError`` as :func:`correspond_parts` does, naming the pair.
    """
    cfg = (cage or CageConfig()).validate()
    if cfg.symmetry:  # symmetry axes are found per pair's seed: the single solver
        return [correspond_parts(v, f, tpl_vertices, tpl_faces, "cage", n_points, seed, cfg, template_points=template_points) for v, f, seed in sources]
    t0 = time.perf_counter()
    pairs = []
    for i, (src_v, src_f, seed) in enumerate(sources):
        try:
            pairs.append(prepare_cage_pair(src_v, src_f, tpl_vertices, tpl_faces, n_points, seed, cfg, template_points))
        except ValueError as exc:
            raise ValueError(f"pair {i}: {exc}") from exc
    if not pairs:
        return []
    results = solve_prepared(pairs, cfg, search)
    return [finish_cage_pair(pair, cfg, res, t0) for pair, res in zip(pairs, results)]


@dataclass
class PreparedCagePair:
    """A cage pair ready for the solver (:func:`prepare_cage_pair`): its pre-aligned source and
    template frames (``prep``), the solver's inputs (``problem``) and the template samples
    ``template_samples (m, 3)`` its Chamfer figure is measured on. Picklable: a worker process
    prepares it, another solves it."""

    prep: _Prepared
    problem: CageProblem
    template_samples: np.ndarray


def prepare_cage_pair(
    src_v: np.ndarray, src_f: np.ndarray, tpl_vertices: np.ndarray, tpl_faces: np.ndarray, n_points: int, seed: int, cage: CageConfig, template_points: int = 3000
) -> PreparedCagePair:
    """What :func:`correspond_parts` with method "cage" does before the solver: validate, sample
    and pre-align the source part (:func:`prepare`), sample the template. ``ValueError`` as there."""
    prep = prepare(src_v, src_f, tpl_vertices, tpl_faces, n_points, seed, prealign=cage.prealign)
    rng = np.random.default_rng(seed + 1)
    tpl_s, tpl_sf, _ = sample_surface(prep.index.vertices, prep.index.faces, template_points, seed=rng)
    return PreparedCagePair(prep, _cage_problem(prep, prep.aligned(prep.samples), tpl_s, tpl_sf, seed), tpl_s)


def solve_prepared(pairs: Sequence[PreparedCagePair], cage: CageConfig, search: str | None = None) -> list[CageResult]:
    """The cage solves of prepared pairs onto one template part, batched
    (:func:`proctex.correspond.cage_batch.solve_cages`, ``search`` as there); one result per pair."""
    index = pairs[0].prep.index
    return solve_cages([p.problem for p in pairs], index, vertex_normals(index.vertices, index.faces), cage, search=search)


def finish_cage_pair(pair: PreparedCagePair, cage: CageConfig, result: CageResult, t0: float) -> PartCorrespondence:
    """A prepared pair and its solved cage as the correspondence :func:`correspond_parts` returns
    (the sweep chart's map where that fits better); ``t0``: when its work began (``seconds``)."""
    return _cage_finish(pair.prep, cage, result, (), pair.template_samples, t0)


def _sweep_candidate(prep: _Prepared, cage: CageConfig | None, cage_points: np.ndarray, tpl_s: np.ndarray):
    """The sweep-chart map of a tube-like pair (:mod:`proctex.correspond.sweep`) when it fits the
    template better than the cage did: ``(moved (n, 3) in the template's normalised frame,
    SweepField)``, else None. Only when ``cage.sweep`` is on, both parts' charts are tubes
    (:attr:`proctex.geometry.chart.SweepChart.tubular`) with an aspect of at least
    ``cage.sweep_aspect`` and their centre lines' turns differ by at least
    ``cage.sweep_turns`` (where the winding is the same, the cage follows the part as well or
    better: mug handles and stair rails lost 0.002-0.003 of GT mean when every tube-like pair
    took the chart)."""
    if cage is None or not cage.sweep:
        return None
    from .sweep import sweep_field, template_chart

    tpl_chart = template_chart(prep.index.vertices, prep.index.faces)
    if tpl_chart is None or tpl_chart.aspect < cage.sweep_aspect or not tpl_chart.tubular:
        return None
    src_norm = (prep.src_v - prep.src_center) / prep.src_radius
    try:
        field = sweep_field(src_norm, prep.src_f, tpl_chart, np.concatenate([prep.s * prep.R, prep.t[:, None]], axis=1), prep.src_center, prep.src_radius)
    except ValueError:
        return None
    if field.source.aspect < cage.sweep_aspect or not field.source.tubular or abs(field.source.turns - tpl_chart.turns) < cage.sweep_turns:
        return None
    s = interpolate(field.source_s[:, None], prep.src_f, prep.sample_faces, prep.sample_bary)[:, 0]
    moved = field.map_normalised((prep.samples - prep.src_center) / prep.src_radius, s)
    if not np.isfinite(moved).all() or not chamfer(moved, tpl_s) < chamfer(cage_points, tpl_s):
        return None
    return moved, field


def deform(result: PartCorrespondence, points: np.ndarray, tpl_center: np.ndarray, tpl_radius: float) -> np.ndarray:
    """Where a correspondence sends arbitrary source points (world), before projection.

    ``nearest``: the similarity pre-alignment; ``cage``: the pre-alignment, then the optimised cage
    deformation (mean value coordinates w.r.t. the initial cage, applied to the optimised one);
    ``cpd``: the pre-alignment, then the fitted CPD displacement field (defined everywhere).
    Returns (n, 3) float64 points in the template part's normalised frame (``tpl_center``,
    ``tpl_radius``: that frame).
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or not np.isfinite(pts).all():
        raise ValueError(f"points must be a finite (n, 3) array, got {pts.shape}")
    aligned = (result.alignment.apply(pts) - tpl_center) / tpl_radius
    if result.method == "nearest":
        return aligned
    if result.method == "cpd":
        if "field" not in result.details:
            raise ValueError("this CPD correspondence carries no fitted field")
        return result.details["field"].transform(aligned)
    if result.method != "cage":
        raise ValueError(f"deform needs a cage, nearest or cpd correspondence, got {result.method!r}")
    if result.details.get("teacher") == "sweep":
        return result.details["sweep"].transform_world(pts)
    from .mvc import mean_value_coordinates

    cage0, cage, faces = result.details["cage0"], result.details["cage"], result.details["cage_faces"]
    W = mean_value_coordinates(aligned, cage0, faces)
    return (W.cpu().numpy() if hasattr(W, "cpu") else np.asarray(W)) @ np.asarray(cage, dtype=np.float64)


# ------------------------------------------------------------------------------------ whole shapes
@dataclass
class GroupCorrespondence:
    """One matched group pair: the shape member and template part used, the result, and the
    ground-truth error (None when either shape has no canonical coordinates)."""

    shape_group: int
    template_group: int
    shape_part: int
    template_part: int
    result: PartCorrespondence
    gt: GTError | None

    def to_dict(self) -> dict[str, Any]:
        r = self.result
        return {
            "group": self.template_group,
            "shape_group": self.shape_group,
            "shape_part": self.shape_part,
            "template_part": self.template_part,
            "seconds": r.seconds,
            "residual": r.residual,
            "chamfer": r.chamfer,
            "converged": r.converged,
            "iterations": r.iterations,
            "oriented": r.oriented,
            "gt_error": None if self.gt is None else self.gt.to_dict(),
        }


@dataclass
class ShapeCorrespondence:
    """Every matched, non-degenerate group pair of a shape against the template."""

    method: str
    match: GroupMatch
    groups: list[GroupCorrespondence]
    skipped: list[dict[str, Any]]
    seconds: float

    def to_dict(self) -> dict[str, Any]:
        return {
            "method": self.method,
            "seconds": self.seconds,
            "groups": [g.to_dict() for g in self.groups],
            "skipped": self.skipped,
            "match": self.match.to_dict(),
        }


def choose_member(shape: Shape, grouping: Grouping, group: PartGroup, template: Shape, template_grouping: Grouping, template_group: PartGroup) -> int:
    """The member of ``group`` lying where the template group's representative lies.

    Member centres are compared in the template's frame after the per-axis map taking the shape's
    bounding box onto the template's, so a mirrored member (a left armrest) is paired with the
    template's member on the same side rather than its reflection.
    """
    if len(group.members) == 1:
        return group.representative
    s_used = shape.vertices[np.unique(shape.faces)]
    t_used = template.vertices[np.unique(template.faces)]
    s_lo, s_ext = s_used.min(0), np.maximum(s_used.max(0) - s_used.min(0), 1e-12)
    t_lo, t_ext = t_used.min(0), np.maximum(t_used.max(0) - t_used.min(0), 1e-12)
    target = (template_grouping.parts[template_group.representative].center - t_lo) / t_ext
    centers = np.array([(grouping.parts[m].center - s_lo) / s_ext for m in group.members])
    return int(group.members[int(np.argmin(np.linalg.norm(centers - target, axis=1)))])


def correspond_shapes(
    shape: Shape,
    template: Shape,
    method: str = "cage",
    n_points: int = 2000,
    seed: int = 0,
    cage: CageConfig | None = None,
    grouping: Grouping | None = None,
    template_grouping: Grouping | None = None,
    on_group: Callable[[GroupCorrespondence], None] | None = None,
    **options: Any,
) -> ShapeCorrespondence:
    """Match part groups and solve every matched, non-degenerate group pair.

    Ground-truth errors are computed when both shapes carry canonical coordinates (built-in models).
    ``on_group`` is called after each solved pair (progress reporting); other keyword ``options``
    go to :func:`correspond_parts` (e.g. ``cpd_beta``).
    """
    if method not in METHODS:
        raise ValueError(f"unknown correspondence method {method!r}; expected one of {', '.join(METHODS)}")
    t0 = time.perf_counter()
    grouping = grouping or analyse(shape)
    template_grouping = template_grouping or analyse(template)
    match = match_groups(shape, grouping, template, template_grouping, seed=seed)
    out: list[GroupCorrespondence] = []
    skipped: list[dict[str, Any]] = []
    for gi, (a, b) in enumerate(match.pairs):
        ga, gb = grouping.groups[a], template_grouping.groups[b]
        if ga.degenerate or gb.degenerate:
            skipped.append({"shape_group": a, "group": b, "reason": "degenerate part (no surface)"})
            continue
        sp = choose_member(shape, grouping, ga, template, template_grouping, gb)
        tp = gb.representative
        sv, sf = part_mesh(shape, grouping.parts[sp])
        tv, tf = part_mesh(template, template_grouping.parts[tp])
        res = correspond_parts(sv, sf, tv, tf, method=method, n_points=n_points, seed=seed + 7919 * gi, cage=cage, **options)
        gt = None
        if shape.canonical is not None and template.canonical is not None and shape.face_source is None:  # built-ins' (a .blend's truth is per node)
            sc = shape.canonical[grouping.parts[sp].vertices]
            src_can = interpolate(sc, sf, res.source_faces, res.source_bary)
            tc = template.canonical[template_grouping.parts[tp].vertices]
            gt = gt_correspondence_error(src_can, res.points, res.faces, tv, tf, tc)
        item = GroupCorrespondence(a, b, sp, tp, res, gt)
        out.append(item)
        if on_group is not None:
            on_group(item)
    return ShapeCorrespondence(method, match, out, skipped, time.perf_counter() - t0)
