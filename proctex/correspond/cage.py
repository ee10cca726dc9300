"""Per-pair cage deformation (the modified neural cage of ProcTex, optimised per pair).

The source part, already similarity-aligned into the template part's normalised frame, is enclosed by
a subdivided, slightly inflated axis-aligned box cage. Every source sample is written once in mean
value coordinates of that cage (:mod:`proctex.correspond.mvc`); moving the cage vertices moves the samples
smoothly (``x' = W @ C'``). Adam moves the cage vertices to minimise

- a Chamfer term between deformed source samples and template samples, matches restricted to
  agreeing normals. By default (``chamfer="plane"``) only the template-to-source direction, measured
  to the tangent plane of the matched deformed sample: zero whenever the surfaces coincide, so two
  identical parts stay matched vertex for vertex (the point-to-point form of both directions,
  ``chamfer="point"``, pulls samples towards the other set's samples: 0.006-0.025 of drift on two
  identical mug parts). Measured on 3 random shapes each of mug, chair, table, desk, vase and sofa
  (``tests/bench/bench_correspond.py --methods cage --chamfer plane|point``), ground-truth error
  fell on every model: mug 0.029 -> 0.020, chair 0.0128 -> 0.0103, table 0.043 -> 0.042, desk
  0.0087 -> 0.0067, vase 0.099 -> 0.064, sofa 0.0121 -> 0.0105, at the same cost;
- a point-to-surface term: squared distance from every deformed sample to its closest template
  point among faces whose normal agrees (KD-tree candidates, exact point-triangle distance;
  :meth:`proctex.geometry.surface.SurfaceIndex.query_oriented`). With the match held fixed, the gradient of
  the squared distance is exact;
- a normal term: ``1 - cos`` between the normals of the *deformed source triangles* and the
  matched template face normals (``normal_target="face"``; interpolated vertex normals with
  ``"vertex"``), so a thin wall cannot map its inside onto its outside;
- a rest term: the mean squared cage displacement (``w_rest``), the least motion that fits;
- a penalty on negative mean value coordinates of deformed samples with respect to the deformed
  cage (a folded cage produces them);
- a smoothness term on the cage displacement (second differences along the cage lattice, zero for
  any affine deformation) and, optionally, mirror symmetry of the cage across the template's
  symmetry planes.

The learning rate decays exponentially; the loop stops early when the loss stops improving, and
the iterate with the lowest loss is returned (``keep_best``).

Adam's steps do not shrink with the gradient, so any term that is not exactly zero at a perfect
start moves it by about the learning rate: the vertex-normal target (never zero on a coarse
template) and the absence of a rest term drifted an exact box-to-box start by 0.01 and a vase by
0.03 (ground-truth error, ``tests/bench/bench_correspond.py``). Face normals, the rest term and the
best iterate keep such a start (the defaults).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch
from scipy.spatial import cKDTree

from proctex.geometry.primitives import box
from proctex.geometry.surface import SurfaceIndex
from proctex.geometry.surface import interpolate
from .mvc import mean_value_coordinates
from proctex.torch_kernels import resolve_vml

resolve_vml()  # MKL's kernels chosen on one thread (see proctex.torch_kernels)

#: Pre-alignments of a source part (:attr:`CageConfig.prealign`).
PREALIGNS = ("icp", "box", "affine", "auto")


@dataclass
class CageConfig:
    """Settings of the cage solver (lengths in the template part's normalised frame, radius 1).

    Attributes:
        level: cage subdivision; the box has ``2**level`` segments per axis.
        elongation: at most this many times ``2**level`` segments along an axis longer than the
            box's median side (:func:`cage_divisions`; 1: the same on every axis).
        margin: inflation of the bounding box, as a share of its largest side.
        iterations: maximum Adam steps; lr: initial learning rate; lr_final: the rate reached
            (exponential decay) at ``iterations``.
        patience, tol: stop when the loss has not improved by a relative ``tol`` for ``patience``
            steps (the run is then *converged*). patience_start: the patience while the loss has
            not improved on the start at all (the pre-alignment already fits: the best iterate
            is the start), at most ``patience``. 91% of the real sofa export's pairs and 64-92%
            of the .blend families' and the demo's never improve on their start; 10 rather than
            25 (``tests/bench/bench_correspond.py --methods cage --cage-set patience_start=10``):
            sofa export 16 pairs, the same ground-truth error 0.003785, 0.65 -> 0.51 s a pair;
            8 built-in models, 49 pairs, ground truth 0.009189 -> 0.009151 (fork 0.00354 ->
            0.00371, desk, chair, stair better, the rest equal), 0.73 -> 0.43 s a pair.
        w_*: loss weights. mvc_points, mvc_every: size and period of the negative-MVC penalty's
            sample. symmetry: mirror-symmetric cage across the given planes.
        min_dot: normal agreement required of a match (cosine).
        w_rest: weight of the mean squared cage displacement: the least motion that fits the
            template, so a surface the coarse cage cannot bulge is not fitted by sliding samples
            along it (a vase profile), and a start that already fits stays put.
        normal_target: what the normal term compares the deformed triangles with: "face" (the
            matched template face's normal: zero when the surfaces coincide) or "vertex" (its
            interpolated vertex normals: smooth, but never zero across a coarse or sharp template,
            so Adam drifts a perfect start away).
        keep_best: return the iterate with the lowest loss rather than the last one.
        prealign: the source part's pre-alignment into the template part's frame (used by
            :func:`proctex.correspond.dense.correspond_parts`): "icp" (similarity ICP from the
            identity), "box" (per-axis scale of the normalised bounding boxes), "affine" (the box
            map refined by facet-matched affine ICP,
            :func:`proctex.geometry.align.affine_icp_to_surface`) or "auto" (the box map, replaced
            by its affine refinement where that fits at least as well, or ICP: the one with the
            smaller symmetric Chamfer distance).
        sweep: for a pair of tubes (:attr:`proctex.geometry.chart.SweepChart.tubular`, with a
            sweep-chart aspect, centre-line length over mean radius, of at least
            ``sweep_aspect`` on both) whose centre lines' turns differ by at
            least ``sweep_turns`` (a coil that gained a turn), map along and around the parts
            through their sweep charts (:mod:`proctex.correspond.sweep`) instead of the cage's
            result when that fits the template better by Chamfer distance; the cage can only
            follow the volume.
        chamfer: "plane" (template samples to the deformed source's tangent planes) or "point"
            (point-to-point, both directions); see the module docstring.
        device, dtype: where the optimisation runs (CUDA when asked for and present).
        batch: shapes whose pairs a worker of the build's pairs stage solves together, template
            group by template group, in one tensor program each
            (:func:`proctex.correspond.dense.correspond_parts_batch`: every step of every pair in
            the same batched products; on CUDA, matches searched on the GPU). 0: each pair alone
            on the CPU; on CUDA, the workers prepare the pairs and the build's own process solves
            every group's in one program on its GPU (:func:`proctex.build.pairs.solves_here`).
    """

    level: int = 1
    elongation: int = 1
    margin: float = 0.1
    iterations: int = 300
    lr: float = 0.02
    lr_final: float = 0.002
    patience: int = 25
    patience_start: int = 10
    tol: float = 1e-3
    w_chamfer: float = 1.0
    w_surface: float = 1.0
    w_normal: float = 0.02
    w_mvc: float = 0.1
    w_smooth: float = 0.1
    w_symmetry: float = 1.0
    mvc_points: int = 64
    mvc_every: int = 10
    symmetry: bool = False
    min_dot: float = 0.0
    chamfer: str = "plane"
    w_rest: float = 0.1
    normal_target: str = "face"
    keep_best: bool = True
    prealign: str = "auto"
    sweep: bool = True
    sweep_aspect: float = 12.0
    sweep_turns: float = 0.5
    device: str = "cpu"
    dtype: str = "float64"
    batch: int = 0

    def validate(self) -> "CageConfig":
        if not 0 <= int(self.level) <= 4:
            raise ValueError(f"cage level must be in 0..4, got {self.level}")
        if not isinstance(self.elongation, (int, np.integer)) or not 1 <= int(self.elongation) <= 8:
            raise ValueError(f"cage elongation must be an integer in 1..8, got {self.elongation!r}")
        if not self.margin >= 0 or not np.isfinite(self.margin):
            raise ValueError(f"cage margin must be >= 0, got {self.margin}")
        if not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= 1 for v in (self.patience, self.patience_start)):
            raise ValueError(f"cage patience and patience_start must be integers >= 1, got {self.patience!r}, {self.patience_start!r}")
        if int(self.iterations) < 1 or not self.lr > 0 or not self.lr_final > 0:
            raise ValueError("cage iterations must be >= 1 and learning rates > 0")
        if self.chamfer not in ("plane", "point"):
            raise ValueError(f"chamfer must be plane or point, got {self.chamfer!r}")
        if self.normal_target not in ("face", "vertex"):
            raise ValueError(f"normal_target must be face or vertex, got {self.normal_target!r}")
        if self.prealign not in PREALIGNS:
            raise ValueError(f"prealign must be one of {', '.join(PREALIGNS)}, got {self.prealign!r}")
        if not isinstance(self.sweep, bool) or not all(isinstance(x, (int, float)) and np.isfinite(x) and x > 0 for x in (self.sweep_aspect, self.sweep_turns)):
            raise ValueError(f"sweep must be true or false and sweep_aspect, sweep_turns positive numbers, got {self.sweep!r}, {self.sweep_aspect!r}, {self.sweep_turns!r}")
        weights = {k: getattr(self, k) for k in ("w_chamfer", "w_surface", "w_normal", "w_mvc", "w_smooth", "w_symmetry", "w_rest")}
        bad = [k for k, v in weights.items() if not (isinstance(v, (int, float)) and np.isfinite(v) and v >= 0)]
        if bad:
            raise ValueError(f"cage weights must be finite numbers >= 0: {', '.join(bad)}")
        if not isinstance(self.keep_best, bool):
            raise ValueError(f"keep_best must be a bool, got {self.keep_best!r}")
        if self.dtype not in ("float32", "float64"):
            raise ValueError(f"dtype must be float32 or float64, got {self.dtype!r}")
        if not isinstance(self.batch, (int, np.integer)) or isinstance(self.batch, bool) or not 0 <= int(self.batch) <= 256:
            raise ValueError(f"cage batch must be an integer in 0..256, got {self.batch!r}")
        return self


@dataclass
class CageResult:
    """Outcome of :func:`solve_cage` (normalised template frame).

    Attributes:
        points: (n, 3) deformed source samples; normals: (n, 3) their deformed triangle normals.
        cage0, cage: (V, 3) initial and optimised cage vertices; cage_faces: (F, 3).
        iterations: steps taken; converged: stopped by the early-stopping rule (not the limit).
        loss: final loss; history: loss per step (without the periodic negative-MVC penalty);
        terms: final value of each term.
    """

    points: np.ndarray
    normals: np.ndarray
    cage0: np.ndarray
    cage: np.ndarray
    cage_faces: np.ndarray
    iterations: int
    converged: bool
    loss: float
    history: list[float] = field(default_factory=list)
    terms: dict[str, float] = field(default_factory=dict)
    seconds: float = 0.0


def cage_divisions(size: np.ndarray, level: int = 1, elongation: int = 1) -> tuple[int, int, int]:
    """Cells per axis of a cage box of ``size (3,)``: ``2**level`` on every axis, times
    ``min(round(size[a] / median side), elongation)`` on an axis longer than the median side, so a
    long thin part gets cells along its length (where its shape changes) rather than across it."""
    size = np.asarray(size, dtype=float)
    n = 2 ** int(level)
    ref = max(float(np.median(size)), 1e-12)
    mult = np.clip(np.rint(size / ref), 1, max(int(elongation), 1)).astype(int)
    return tuple(int(n * m) for m in mult)  # type: ignore[return-value]


def init_cage(points: np.ndarray, level: int = 1, margin: float = 0.1, symmetric_axes: tuple[int, ...] = (), elongation: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Subdivided, inflated axis-aligned bounding box of ``points (n, 3)``.

    ``symmetric_axes``: axes across whose plane through the origin the box is made symmetric;
    ``elongation``: see :func:`cage_divisions`.
    Returns ``(vertices (V, 3) float64, faces (F, 3) int64)``, closed and outward-oriented.
    """
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0 or not np.all(np.isfinite(pts)):
        raise ValueError("cage points must be a non-empty finite (n, 3) array")
    lo, hi = pts.min(0), pts.max(0)
    for a in symmetric_axes:
        m = max(abs(lo[a]), abs(hi[a]))
        lo[a], hi[a] = -m, m
    pad = margin * float((hi - lo).max()) + 1e-3 * max(float((hi - lo).max()), 1e-9)
    lo, hi = lo - pad, hi + pad
    part = box(hi - lo, (hi + lo) / 2, cage_divisions(hi - lo, level, elongation))
    return part.vertices, part.faces


def lattice_triples(cage: np.ndarray, divisions: tuple[int, int, int]) -> np.ndarray:
    """(t, 3) int64 vertex triples ``(prev, mid, next)`` of consecutive cage lattice points along an axis.

    ``divisions``: the cage box's cells per axis. The second difference ``D[prev] - 2 D[mid] +
    D[next]`` of a displacement ``D`` vanishes for every affine displacement, so penalising it
    smooths the cage without resisting stretch or shear.
    """
    n = np.asarray(divisions, dtype=float)
    lo, hi = cage.min(0), cage.max(0)
    ijk = np.rint((cage - lo) / (hi - lo) * n).astype(np.int64)
    index = {tuple(p): i for i, p in enumerate(ijk)}
    out = []
    for i, p in enumerate(ijk):
        for a in range(3):
            step = np.eye(3, dtype=np.int64)[a]
            prev, nxt = index.get(tuple(p - step)), index.get(tuple(p + step))
            if prev is not None and nxt is not None:
                out.append((prev, i, nxt))
    return np.array(out, dtype=np.int64).reshape(-1, 3)


def _mirror_pairs(cage: np.ndarray, axis: int) -> np.ndarray | None:
    mirrored = cage.copy()
    mirrored[:, axis] *= -1
    d, j = cKDTree(cage).query(mirrored)
    return j if float(d.max()) < 1e-9 * max(float(np.abs(cage).max()), 1.0) else None


def _tri_normals(tri: torch.Tensor) -> torch.Tensor:
    n = torch.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], dim=1)
    return n / torch.sqrt((n * n).sum(1, keepdim=True) + 1e-30)


def _oriented_nn(tree: cKDTree, pts: np.ndarray, pts_normals: np.ndarray, query: np.ndarray, query_normals: np.ndarray, k: int = 8) -> np.ndarray:
    """Index into ``pts`` of each query's nearest point with an agreeing normal among its ``k``
    nearest (else its plain nearest). Most queries' nearest point agrees: only the others are
    asked for ``k`` neighbours (the same answer as asking all for ``k``:
    :func:`proctex._reference.cage.oriented_nn_reference`)."""
    _, j = tree.query(query, k=1)
    j = np.asarray(j, dtype=np.int64).reshape(len(query))
    k = min(k, len(pts))
    bad = np.flatnonzero(np.einsum("qd,qd->q", pts_normals[j], query_normals) <= 0)
    if len(bad) and k > 1:
        _, jk = tree.query(query[bad], k=k)
        jk = np.asarray(jk, dtype=np.int64).reshape(len(bad), k)
        ok = np.einsum("qkd,qd->qk", pts_normals[jk], query_normals[bad]) > 0
        j[bad] = jk[np.arange(len(bad)), np.where(ok.any(1), np.argmax(ok, axis=1), 0)]
    return j


def warm_offset(start: tuple[np.ndarray, np.ndarray], cage0: np.ndarray) -> np.ndarray | None:
    """The displacement of a solved cage ``start = (its initial cage, its solved cage)`` carried onto
    a new initial cage ``cage0 (V, 3)``: per axis, scaled by the ratio of the two cages' box extents
    (the box map between them), so a neighbour's stretch or bend lands where this pair's cage has
    the same lattice vertex. None when the cages have different lattices (vertex counts or
    layouts: no warm start)."""
    c0 = np.asarray(start[0], dtype=np.float64)
    if c0.shape != cage0.shape:
        return None
    lo0, hi0 = c0.min(0), c0.max(0)
    lo1, hi1 = cage0.min(0), cage0.max(0)
    scale = (hi1 - lo1) / np.maximum(hi0 - lo0, 1e-12)
    # the same lattice: each vertex at the same relative place in its box
    if not np.allclose((c0 - lo0) * scale, cage0 - lo1, atol=1e-9 * max(float((hi1 - lo1).max()), 1e-9)):
        return None
    out = (np.asarray(start[1], dtype=np.float64) - c0) * scale
    return out if np.isfinite(out).all() else None


def _data_terms(xd: np.ndarray, nd: np.ndarray, template: SurfaceIndex, template_samples: np.ndarray, template_sample_normals: np.ndarray, cfg: CageConfig) -> float:
    """The surface and plane-Chamfer terms of deformed samples ``xd`` with normals ``nd`` (what a
    warm start is judged by: how well the cage fits, not how far it moved)."""
    cp, _ = template.query_oriented(xd, nd, cfg.min_dot, k=8, exact=False)
    surface = float(((xd - cp.points) ** 2).sum(1).mean())
    bwd = _oriented_nn(cKDTree(xd), xd, nd, template_samples, template_sample_normals)
    chamfer = float((((template_samples - xd[bwd]) * nd[bwd]).sum(1) ** 2).mean())
    return cfg.w_surface * surface + cfg.w_chamfer * chamfer


def solve_cage(
    points: np.ndarray,
    tri_vertices: np.ndarray,
    tri_faces: np.ndarray,
    tri_index: np.ndarray,
    template: SurfaceIndex,
    template_vertex_normals: np.ndarray,
    template_samples: np.ndarray,
    template_sample_normals: np.ndarray,
    config: CageConfig | None = None,
    symmetry_axes: tuple[int, ...] = (),
    seed: int = 0,
    start: tuple[np.ndarray, np.ndarray] | None = None,
) -> CageResult:
    """Optimise a cage deforming the source samples onto the template surface.

    Args:
        points: (n, 3) float64 aligned source samples (normalised template frame).
        tri_vertices: (k, 3) float64 aligned source vertices; tri_faces: (f, 3) int64 the source
            triangles the samples lie on (into ``tri_vertices``).
        tri_index: (n,) int64 triangle of each sample (into ``tri_faces``).
        template: exact-distance index of the template part (same frame).
        template_vertex_normals: (Vt, 3) unit vertex normals of the template part.
        template_samples, template_sample_normals: (m, 3) uniform template samples and normals.
        config: solver settings. symmetry_axes: template mirror planes ``x[axis] = 0`` (used when
            ``config.symmetry``). seed: seed of the penalty's subsamples.
        start: a warm start: ``(initial cage, solved cage)`` of a neighbouring pair (its
            displacement carried onto this pair's cage by :func:`warm_offset`, composed with the
            box map between the two cages). The first step measures both the rest cage and the carried one and goes on
            from the better, so a poor neighbour costs one loss evaluation, never the result.
    """
    cfg = (config or CageConfig()).validate()
    t0 = time.perf_counter()
    device = torch.device(cfg.device if (cfg.device != "cuda" or torch.cuda.is_available()) else "cpu")
    dtype = torch.float64 if cfg.dtype == "float64" else torch.float32
    rng = np.random.default_rng(seed)
    axes = tuple(symmetry_axes) if cfg.symmetry else ()
    cage0, cage_faces = init_cage(np.concatenate([points, tri_vertices]), cfg.level, cfg.margin, axes, cfg.elongation)
    # Every sample and every triangle corner in mean value coordinates of the initial cage.
    W_pts = mean_value_coordinates(points, cage0, cage_faces).to(device, dtype)
    W_tri = mean_value_coordinates(tri_vertices, cage0, cage_faces).to(device, dtype)
    tf = torch.as_tensor(np.asarray(tri_faces, dtype=np.int64), device=device)
    tidx = torch.as_tensor(np.asarray(tri_index, dtype=np.int64), device=device)
    faces_t = torch.as_tensor(cage_faces, device=device)
    C0 = torch.as_tensor(cage0, device=device, dtype=dtype)
    offset = torch.zeros_like(C0, requires_grad=True)
    warm = warm_offset(start, cage0) if start is not None else None
    triples = torch.as_tensor(lattice_triples(cage0, cage_divisions(cage0.max(0) - cage0.min(0), cfg.level, cfg.elongation)), device=device)
    pairs = [(a, p) for a in axes if (p := _mirror_pairs(cage0, a)) is not None]
    flips = {a: torch.as_tensor([-1.0 if i == a else 1.0 for i in range(3)], device=device, dtype=dtype) for a, _ in pairs}
    T = torch.as_tensor(template_samples, device=device, dtype=dtype)
    t_tree = cKDTree(template_samples) if cfg.chamfer == "point" else None  # the plane Chamfer asks only the deformed samples
    vn = np.asarray(template_vertex_normals, dtype=float)
    tfaces = template.faces

    opt = torch.optim.Adam([offset], lr=cfg.lr)
    gamma = (cfg.lr_final / cfg.lr) ** (1.0 / max(cfg.iterations, 1))
    sched = torch.optim.lr_scheduler.ExponentialLR(opt, gamma=gamma)
    best, since, history, improved = np.inf, 0, [], False
    best_value, best_offset = np.inf, offset.detach().clone()
    converged = False
    terms: dict[str, float] = {}
    mvc_term = torch.zeros((), device=device, dtype=dtype)
    it = 0

    def fit(C: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, np.ndarray, np.ndarray]:
        x = W_pts @ C
        nrm = _tri_normals((W_tri @ C)[tf])[tidx]
        return x, nrm, x.detach().cpu().numpy(), nrm.detach().cpu().numpy()

    if warm is not None:  # from the carried cage where it fits better than the rest cage
        with torch.no_grad():
            W = torch.as_tensor(warm, device=device, dtype=dtype)
            fits = [_data_terms(*fit(C0 + o)[2:], template, template_samples, template_sample_normals, cfg) for o in (torch.zeros_like(W), W)]
        if fits[1] < fits[0]:
            with torch.no_grad():
                offset.copy_(W)
    for it in range(1, cfg.iterations + 1):
        C = C0 + offset
        x, nrm, xd, nd = fit(C)
        # Point-to-surface matches with agreeing normals (gradient of |x - q|^2 exact for fixed q).
        cp, _ = template.query_oriented(xd, nd, cfg.min_dot, k=8, exact=False)
        q = torch.as_tensor(cp.points, device=device, dtype=dtype)
        if cfg.normal_target == "face":
            qn = template.normals[cp.faces]
        else:
            qn = interpolate(vn, tfaces, cp.faces, cp.bary)
            qn /= np.maximum(np.linalg.norm(qn, axis=1, keepdims=True), 1e-12)
        surface = ((x - q) ** 2).sum(1).mean()
        normal = (1.0 - (nrm * torch.as_tensor(qn, device=device, dtype=dtype)).sum(1)).mean()
        # Chamfer between point sets, both directions, matches with agreeing normals.
        bwd = _oriented_nn(cKDTree(xd), xd, nd, template_samples, template_sample_normals)
        if cfg.chamfer == "plane":
            # Template samples to the tangent planes of their nearest deformed source samples: zero
            # when the surfaces coincide, whatever the two sample sets (point-to-point is not).
            chamfer = (((T - x[bwd]) * nrm[bwd]).sum(1) ** 2).mean()
        else:
            fwd = _oriented_nn(t_tree, template_samples, template_sample_normals, xd, nd)
            chamfer = ((x - T[fwd]) ** 2).sum(1).mean() + ((T - x[bwd]) ** 2).sum(1).mean()
        smooth = ((offset[triples[:, 0]] - 2 * offset[triples[:, 1]] + offset[triples[:, 2]]) ** 2).sum(1).mean() if len(triples) else torch.zeros((), device=device, dtype=dtype)
        rest = (offset**2).sum(1).mean()
        loss = cfg.w_surface * surface + cfg.w_chamfer * chamfer + cfg.w_normal * normal + cfg.w_smooth * smooth + cfg.w_rest * rest
        if pairs:
            sym = sum(((C[p] * flips[a] - C) ** 2).sum(1).mean() for a, p in pairs)
            loss = loss + cfg.w_symmetry * sym
        # Early stopping watches the terms computed every step (the MVC penalty is periodic).
        value = float(loss.detach())
        if value < best_value:  # the state this loss belongs to (before the step below)
            best_value, best_offset = value, offset.detach().clone()
        if cfg.w_mvc > 0 and (it - 1) % max(cfg.mvc_every, 1) == 0:
            sub = rng.choice(len(points), size=min(cfg.mvc_points, len(points)), replace=False)
            Wd = mean_value_coordinates(x[torch.as_tensor(sub, device=device)], C, faces_t)
            mvc_term = torch.relu(-Wd).sum(1).mean()
            loss = loss + cfg.w_mvc * mvc_term
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        history.append(value)
        terms = {
            "surface": float(surface.detach()),
            "chamfer": float(chamfer.detach()),
            "normal": float(normal.detach()),
            "smooth": float(smooth.detach()),
            "rest": float(rest.detach()),
            "negative_mvc": float(mvc_term.detach()),
        }
        if value < best * (1 - cfg.tol):
            improved, best, since = it > 1, value, 0
        else:
            since += 1
            if since >= (cfg.patience if improved else min(cfg.patience, cfg.patience_start)):
                converged = True
                break
    with torch.no_grad():
        C = C0 + (best_offset if cfg.keep_best else offset)
        x = (W_pts @ C).cpu().numpy()
        nrm = _tri_normals((W_tri @ C)[tf])[tidx].cpu().numpy()
    return CageResult(
        points=x,
        normals=nrm,
        cage0=cage0,
        cage=C.cpu().numpy().astype(np.float64),
        cage_faces=cage_faces,
        iterations=it,
        converged=converged,
        loss=(best_value if cfg.keep_best else history[-1]) if history else float("nan"),
        history=history,
        terms=terms,
        seconds=time.perf_counter() - t0,
    )
