"""The cage solver for a batch of pairs onto one template part (:func:`solve_cages`).

Every pair of a batch is the problem :func:`proctex.correspond.cage.solve_cage` solves (its own
source samples, cage, template samples and seed) against the same template part: one shape's part
after another onto one group of the template. The batch runs as one tensor program per iteration:
the pairs' cages stacked ``(B, V, 3)``, their samples moved by one batched product, every pair's
matches found in one query of the shared template index and one KD-tree over all pairs' deformed
samples (each pair shifted far from the others along x, so no match crosses pairs), the losses
computed per pair and summed, so each pair's gradient is its own. Adam is written out per pair (the
same update as ``torch.optim.Adam``) so a pair that has converged leaves the batch: it is neither
moved nor computed again, and its result is the one the single solver returns, to float rounding.

On a GPU the matches are found there instead (``search="device"``, the default on CUDA): exact
distances in torch to every pair's own samples (:func:`oriented_nn`) and to the template's faces
with the nearest centroids (:func:`closest_oriented`), so a step leaves the device only for the
pairs' figures (one read a step).

Pairs whose cage lattices differ (another elongation of the box, :func:`cage_divisions`) or sample
counts differ are solved in separate buckets; a symmetric cage (``config.symmetry``) falls back to
the single solver per pair.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch
from scipy.spatial import cKDTree

from proctex.geometry.surface import SurfaceIndex, interpolate
from .cage import CageConfig, CageResult, _oriented_nn, _tri_normals, cage_divisions, init_cage, lattice_triples, solve_cage
from .mvc import _mvc_chunk, mean_value_coordinates
from proctex.torch_kernels import resolve_vml

resolve_vml()  # MKL's kernels chosen on one thread (see proctex.torch_kernels)

#: Adam's constants (``torch.optim.Adam``'s defaults, which the single solver uses).
BETA1, BETA2, EPS = 0.9, 0.999, 1e-8


@dataclass
class CageProblem:
    """One pair's inputs (the template part's normalised frame), as :func:`solve_cage` takes them.

    Attributes:
        points: (n, 3) aligned source samples; tri_vertices (k, 3), tri_faces (f, 3) int64: the
            source triangles they lie on; tri_index: (n,) int64 triangle of each sample.
        template_samples, template_sample_normals: (m, 3) this pair's template samples and normals.
        seed: seed of the pair's penalty subsamples.
    """

    points: np.ndarray
    tri_vertices: np.ndarray
    tri_faces: np.ndarray
    tri_index: np.ndarray
    template_samples: np.ndarray
    template_sample_normals: np.ndarray
    seed: int = 0


def solve_cages(
    problems: Sequence[CageProblem],
    template: SurfaceIndex,
    template_vertex_normals: np.ndarray,
    config: CageConfig | None = None,
    symmetry_axes: tuple[int, ...] = (),
    search: str | None = None,
) -> list[CageResult]:
    """Solve every pair of ``problems`` onto the one ``template`` part; one :class:`CageResult` per
    problem, in order, each what :func:`solve_cage` returns for it alone (to float rounding of the
    batched products; ``seconds``: its bucket's wall time).

    ``search``: where each step's matches are found. "host": the template's :class:`SurfaceIndex`
    and a KD-tree on the CPU (the single solver's searches); "device": exact distances on the
    solver's device (:func:`closest_oriented`, :func:`oriented_nn`), so a step never leaves a GPU
    but for its losses; None: "device" where the solver runs on CUDA, else "host"."""
    cfg = (config or CageConfig()).validate()
    if search not in (None, "host", "device"):
        raise ValueError(f"search must be 'host' or 'device', got {search!r}")
    problems = list(problems)
    out: list[CageResult | None] = [None] * len(problems)
    axes = tuple(symmetry_axes) if cfg.symmetry else ()
    buckets: dict[tuple, list[int]] = {}
    cages: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for i, p in enumerate(problems):
        if axes:  # a symmetric cage pairs mirrored vertices per pair: the single solver
            out[i] = solve_cage(
                p.points, p.tri_vertices, p.tri_faces, p.tri_index, template, template_vertex_normals, p.template_samples, p.template_sample_normals, cfg, symmetry_axes=axes, seed=p.seed
            )
            continue
        cages[i] = init_cage(np.concatenate([p.points, p.tri_vertices]), cfg.level, cfg.margin, (), cfg.elongation)
        size = cages[i][0].max(0) - cages[i][0].min(0)
        key = (cage_divisions(size, cfg.level, cfg.elongation), len(p.points), len(p.template_samples))
        buckets.setdefault(key, []).append(i)
    for rows in buckets.values():
        for i, res in zip(rows, _solve_bucket([problems[i] for i in rows], [cages[i] for i in rows], template, template_vertex_normals, cfg, search)):
            out[i] = res
    return out  # type: ignore[return-value]


def _solve_bucket(
    problems: list[CageProblem], cages: list[tuple[np.ndarray, np.ndarray]], template: SurfaceIndex, template_vertex_normals: np.ndarray, cfg: CageConfig, search: str | None = None
) -> list[CageResult]:
    """One bucket's pairs (the same cage lattice and sample counts), with their initial cages."""
    t0 = time.perf_counter()
    device = torch.device(cfg.device if (cfg.device != "cuda" or torch.cuda.is_available()) else "cpu")
    dtype = torch.float64 if cfg.dtype == "float64" else torch.float32
    resident = (search or ("device" if device.type == "cuda" else "host")) == "device"
    B = len(problems)
    n = len(problems[0].points)
    rngs = [np.random.default_rng(p.seed) for p in problems]
    cage_faces = cages[0][1]
    cage0 = np.stack([c[0] for c in cages])  # (B, V, 3)
    V = cage0.shape[1]

    def weights(points: np.ndarray, cage: np.ndarray) -> torch.Tensor:
        if resident:  # computed where they are used
            return mean_value_coordinates(torch.as_tensor(points, device=device, dtype=dtype), torch.as_tensor(cage, device=device, dtype=dtype), cage_faces)
        return mean_value_coordinates(points, cage, cage_faces).to(device, dtype)

    W_pts = torch.stack([weights(p.points, c) for p, (c, _) in zip(problems, cages)])  # (B, n, V)
    k_max = max(len(p.tri_vertices) for p in problems)
    f_max = max(len(p.tri_faces) for p in problems)
    W_tri = torch.zeros(B, k_max, V, dtype=dtype, device=device)
    tf = torch.zeros(B, f_max, 3, dtype=torch.long, device=device)  # padding: face (0, 0, 0), never sampled
    for b, (p, (c, _)) in enumerate(zip(problems, cages)):
        W_tri[b, : len(p.tri_vertices)] = weights(p.tri_vertices, c)
        tf[b, : len(p.tri_faces)] = torch.as_tensor(np.asarray(p.tri_faces, dtype=np.int64))
    tidx = torch.as_tensor(np.stack([np.asarray(p.tri_index, dtype=np.int64) for p in problems]), device=device)  # (B, n)
    faces_t = torch.as_tensor(cage_faces, device=device)
    C0 = torch.as_tensor(cage0, device=device, dtype=dtype)
    triples = torch.as_tensor(lattice_triples(cage0[0], cage_divisions(cage0[0].max(0) - cage0[0].min(0), cfg.level, cfg.elongation)), device=device)
    T_np = np.stack([p.template_samples for p in problems])  # (B, m, 3)
    Tn_np = np.stack([p.template_sample_normals for p in problems])
    T = torch.as_tensor(T_np, device=device, dtype=dtype)
    vn = np.asarray(template_vertex_normals, dtype=float)
    if resident:
        surf = DeviceSurface.of(template, device, dtype)
        Tn = torch.as_tensor(Tn_np, device=device, dtype=dtype)
        vn_t = torch.as_tensor(vn, device=device, dtype=dtype)
        tfaces_t = torch.as_tensor(np.asarray(template.faces, dtype=np.int64), device=device)

    offset = torch.zeros_like(C0)
    exp_avg, exp_avg_sq = torch.zeros_like(C0), torch.zeros_like(C0)
    best_offset = offset.clone()
    best_value = np.full(B, np.inf)
    best, since, improved = np.full(B, np.inf), np.zeros(B, dtype=int), np.zeros(B, dtype=bool)
    histories: list[list[float]] = [[] for _ in range(B)]
    terms: list[dict[str, float]] = [{} for _ in range(B)]
    iterations, converged = np.zeros(B, dtype=int), np.zeros(B, dtype=bool)
    mvc_term = torch.zeros(B, device=device, dtype=dtype)
    gamma = (cfg.lr_final / cfg.lr) ** (1.0 / max(cfg.iterations, 1))
    lr = cfg.lr
    active = np.arange(B)
    for it in range(1, cfg.iterations + 1):
        a = len(active)
        A = torch.as_tensor(active, device=device)
        off = offset[A].clone().requires_grad_(True)
        C = C0[A] + off  # (a, V, 3)
        x = torch.bmm(W_pts[A], C)  # (a, n, 3)
        xt = torch.bmm(W_tri[A], C)  # (a, k_max, 3)
        ar = torch.arange(a, device=device)
        tri = xt[ar[:, None, None], tf[A]]  # (a, f_max, 3, 3)
        fn = _tri_normals(tri.reshape(-1, 3, 3)).reshape(a, f_max, 3)
        nrm = fn[ar[:, None], tidx[A]]  # (a, n, 3)
        if resident:
            surface, normal, chamfer = _device_terms(x, nrm, T[A], Tn[A], surf, vn_t, tfaces_t, cfg)
        else:
            surface, normal, chamfer = _host_terms(x, nrm, T_np[active], Tn_np[active], T[A], template, vn, cfg)
        if len(triples):
            smooth = ((off[:, triples[:, 0]] - 2 * off[:, triples[:, 1]] + off[:, triples[:, 2]]) ** 2).sum(-1).mean(-1)
        else:
            smooth = torch.zeros(a, device=device, dtype=dtype)
        rest = (off**2).sum(-1).mean(-1)
        loss = cfg.w_surface * surface + cfg.w_chamfer * chamfer + cfg.w_normal * normal + cfg.w_smooth * smooth + cfg.w_rest * rest
        total = loss.sum()
        if cfg.w_mvc > 0 and (it - 1) % max(cfg.mvc_every, 1) == 0:
            subs = np.stack([rngs[b].choice(n, size=min(cfg.mvc_points, n), replace=False) for b in active])  # (a, s)
            S = torch.as_tensor(subs, device=device)
            xs = x.gather(1, S[..., None].expand(-1, -1, 3)).reshape(-1, 3)
            Wd = _mvc_chunk(xs, C.repeat_interleave(S.shape[1], dim=0), faces_t, 1e-9).reshape(a, S.shape[1], V)  # each pair's samples in its own cage
            mvc_rows = torch.relu(-Wd).sum(-1).mean(-1)
            mvc_term[A] = mvc_rows.detach()
            total = total + cfg.w_mvc * mvc_rows.sum()
        # one read of every pair's figures a step (the state each loss belongs to: before the step below)
        stats = torch.stack([loss, surface, chamfer, normal, smooth, rest, mvc_term[A]]).detach().cpu().numpy()
        values = stats[0]
        better = values < best_value[active]
        if better.any():
            best_value[active[better]] = values[better]
            rows = torch.as_tensor(np.flatnonzero(better), device=device)
            best_offset[A[rows]] = off.detach()[rows]
        total.backward()
        g = off.grad
        # Adam, per pair (torch.optim.Adam's update; every active pair is at step ``it``).
        m_, v_ = exp_avg[A], exp_avg_sq[A]
        m_.lerp_(g, 1 - BETA1)
        v_.mul_(BETA2).addcmul_(g, g, value=1 - BETA2)
        step_size = lr / (1 - BETA1**it)
        denom = (v_.sqrt() / math.sqrt(1 - BETA2**it)).add_(EPS)
        offset[A] = off.detach() - step_size * m_ / denom
        exp_avg[A], exp_avg_sq[A] = m_, v_
        lr *= gamma
        keep = []
        for r, b in enumerate(active):
            histories[b].append(float(values[r]))
            terms[b] = {
                "surface": float(stats[1, r]),
                "chamfer": float(stats[2, r]),
                "normal": float(stats[3, r]),
                "smooth": float(stats[4, r]),
                "rest": float(stats[5, r]),
                "negative_mvc": float(stats[6, r]),
            }
            iterations[b] = it
            if values[r] < best[b] * (1 - cfg.tol):
                improved[b], best[b], since[b] = it > 1, values[r], 0
                keep.append(b)
            else:
                since[b] += 1
                if since[b] >= (cfg.patience if improved[b] else min(cfg.patience, cfg.patience_start)):
                    converged[b] = True
                else:
                    keep.append(b)
        active = np.asarray(keep, dtype=int)
        if not len(active):
            break
    seconds = time.perf_counter() - t0
    results = []
    with torch.no_grad():
        for b, p in enumerate(problems):
            C = C0[b] + (best_offset[b] if cfg.keep_best else offset[b])
            xb = (W_pts[b] @ C).cpu().numpy()
            k, f = len(p.tri_vertices), len(p.tri_faces)
            nb = _tri_normals((W_tri[b, :k] @ C)[tf[b, :f]])[tidx[b]].cpu().numpy()
            results.append(
                CageResult(
                    points=xb,
                    normals=nb,
                    cage0=cage0[b],
                    cage=C.cpu().numpy().astype(np.float64),
                    cage_faces=cage_faces,
                    iterations=int(iterations[b]),
                    converged=bool(converged[b]),
                    loss=(float(best_value[b]) if cfg.keep_best else histories[b][-1]) if histories[b] else float("nan"),
                    history=histories[b],
                    terms=terms[b],
                    seconds=seconds,
                )
            )
    return results


def _host_terms(x: torch.Tensor, nrm: torch.Tensor, T_np: np.ndarray, Tn_np: np.ndarray, T: torch.Tensor, template: SurfaceIndex, vn: np.ndarray, cfg: CageConfig):
    """A step's data terms per pair ``(surface, normal, chamfer)``, each (a,), with the matches
    found on the CPU: the template's index and one KD-tree over all pairs' deformed samples (each
    pair shifted far from the others along x, so no match crosses pairs)."""
    a, n = x.shape[:2]
    m = T.shape[1]
    device, dtype = x.device, x.dtype
    xd, nd = x.detach().cpu().numpy().reshape(-1, 3), nrm.detach().cpu().numpy().reshape(-1, 3)
    cp, _ = template.query_oriented(xd, nd, cfg.min_dot, k=8, exact=False)
    q = torch.as_tensor(cp.points.reshape(a, n, 3), device=device, dtype=dtype)
    if cfg.normal_target == "face":
        qn = template.normals[cp.faces]
    else:
        qn = interpolate(vn, template.faces, cp.faces, cp.bary)
        qn /= np.maximum(np.linalg.norm(qn, axis=1, keepdims=True), 1e-12)
    qn_t = torch.as_tensor(qn.reshape(a, n, 3), device=device, dtype=dtype)
    surface = ((x - q) ** 2).sum(-1).mean(-1)  # (a,)
    normal = (1.0 - (nrm * qn_t).sum(-1)).mean(-1)
    Ta, Tna = T_np.reshape(-1, 3), Tn_np.reshape(-1, 3)
    lo = min(float(xd.min()), float(Ta.min()))
    shift = 3.0 * max(float(xd.max()) - lo, float(Ta.max()) - lo, 1.0)
    xs, Ts = xd.copy(), Ta.copy()
    xs[:, 0] += np.repeat(np.arange(a) * shift, n)
    Ts[:, 0] += np.repeat(np.arange(a) * shift, m)
    bwd = _oriented_nn(cKDTree(xs), xs, nd, Ts, Tna)
    x_flat, n_flat = x.reshape(-1, 3), nrm.reshape(-1, 3)
    Tf = T.reshape(-1, 3)
    if cfg.chamfer == "plane":
        chamfer = (((Tf - x_flat[bwd]) * n_flat[bwd]).sum(-1) ** 2).reshape(a, m).mean(-1)
    else:
        fwd = _oriented_nn(cKDTree(Ts), Ts, Tna, xs, nd)
        chamfer = ((x_flat - Tf[fwd]) ** 2).sum(-1).reshape(a, n).mean(-1) + ((Tf - x_flat[bwd]) ** 2).sum(-1).reshape(a, m).mean(-1)
    return surface, normal, chamfer


def _device_terms(x: torch.Tensor, nrm: torch.Tensor, T: torch.Tensor, Tn: torch.Tensor, surf: "DeviceSurface", vn: torch.Tensor, tfaces: torch.Tensor, cfg: CageConfig):
    """:func:`_host_terms` with the matches found on the solver's device (:func:`closest_oriented`,
    :func:`oriented_nn`): nothing leaves it."""
    a, n = x.shape[:2]
    xd, nd = x.detach(), nrm.detach()
    q, qf, qb = closest_oriented(xd.reshape(-1, 3), nd.reshape(-1, 3), surf, cfg.min_dot)
    if cfg.normal_target == "face":
        qn = surf.normals[qf]
    else:
        qn = (vn[tfaces[qf]] * qb[..., None]).sum(1)
        qn = qn / torch.clamp(torch.linalg.norm(qn, dim=1, keepdim=True), min=1e-12)
    surface = ((x - q.reshape(a, n, 3)) ** 2).sum(-1).mean(-1)
    normal = (1.0 - (nrm * qn.reshape(a, n, 3)).sum(-1)).mean(-1)
    bwd = oriented_nn(xd, nd, T, Tn)  # (a, m) into each pair's samples
    xb = x.gather(1, bwd[..., None].expand(-1, -1, 3))
    if cfg.chamfer == "plane":
        chamfer = (((T - xb) * nrm.gather(1, bwd[..., None].expand(-1, -1, 3))).sum(-1) ** 2).mean(-1)
    else:
        fwd = oriented_nn(T, Tn, xd, nd)  # (a, n) into each pair's template samples
        chamfer = ((x - T.gather(1, fwd[..., None].expand(-1, -1, 3))) ** 2).sum(-1).mean(-1) + ((T - xb) ** 2).sum(-1).mean(-1)
    return surface, normal, chamfer


# ----------------------------------------------------------------------------- device-side searches
def closest_on_triangles(p: torch.Tensor, a: torch.Tensor, b: torch.Tensor, c: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Exact closest points on triangles in torch (Ericson's regions, the same as
    :func:`proctex.geometry.surface.closest_point_on_triangles`), for any leading shape.

    Args:
        p, a, b, c: (..., 3) query points and triangle corners, broadcast against each other.

    Returns:
        ``(closest (..., 3), barycentric (..., 3))`` in ``p``'s dtype; degenerate triangles take an
        edge's or a corner's point (a zero-length edge is no region; no region: the nearest corner).
    """
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(-1), (ac * ap).sum(-1)
    bp = p - b
    d3, d4 = (ab * bp).sum(-1), (ac * bp).sum(-1)
    cp = p - c
    d5, d6 = (ab * cp).sum(-1), (ac * cp).sum(-1)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2

    def ratio(num: torch.Tensor, den: torch.Tensor) -> torch.Tensor:
        ok = den != 0
        return torch.where(ok, num / torch.where(ok, den, torch.ones_like(den)), torch.zeros_like(num))

    v_ab, w_ac = ratio(d1, d1 - d3), ratio(d2, d2 - d6)
    w_bc = ratio(d4 - d3, (d4 - d3) + (d5 - d6))
    denom = va + vb + vc
    vv, ww = ratio(vb, denom), ratio(vc, denom)
    one, zero = torch.ones_like(d1), torch.zeros_like(d1)
    # np.select's order (the first region that holds wins): applied last to first.
    regions = [
        ((d1 <= 0) & (d2 <= 0), (one, zero, zero)),
        ((d3 >= 0) & (d4 <= d3), (zero, one, zero)),
        ((d6 >= 0) & (d5 <= d6), (zero, zero, one)),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0) & (d1 - d3 != 0), (1 - v_ab, v_ab, zero)),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0) & (d2 - d6 != 0), (1 - w_ac, zero, w_ac)),
        ((va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0) & ((d4 - d3) + (d5 - d6) != 0), (zero, 1 - w_bc, w_bc)),
        (denom != 0, (1 - vv - ww, vv, ww)),
    ]
    # no region (all corners on one point or line): the nearest corner
    da, db, dc = (ap * ap).sum(-1), (bp * bp).sum(-1), (cp * cp).sum(-1)
    near_a, near_b = (da <= db) & (da <= dc), db <= dc
    bary = [near_a.to(d1.dtype), (~near_a & near_b).to(d1.dtype), (~near_a & ~near_b).to(d1.dtype)]
    for cond, choice in reversed(regions):
        bary = [torch.where(cond, ch, old) for ch, old in zip(choice, bary)]
    w = torch.stack(bary, -1)
    return w[..., :1] * a + w[..., 1:2] * b + w[..., 2:] * c, w


@dataclass
class DeviceSurface:
    """A template part's triangles on a device, for :func:`closest_oriented`: corners ``tri
    (F, 3, 3)``, unit face normals ``normals (F, 3)`` and ``centroids (F, 3)``."""

    tri: torch.Tensor
    normals: torch.Tensor
    centroids: torch.Tensor

    @classmethod
    def of(cls, index: SurfaceIndex, device: torch.device, dtype: torch.dtype) -> "DeviceSurface":
        tri = torch.as_tensor(index.vertices[index.faces], device=device, dtype=dtype)
        return cls(tri, torch.as_tensor(index.normals, device=device, dtype=dtype), tri.mean(1))


#: Candidate faces per query of :func:`closest_oriented` (nearest centroids among admissible faces).
DEVICE_CANDIDATES = 16
#: Query rows per block of the device searches (a block's distance matrix: rows x faces or samples).
DEVICE_BLOCK = 8192


def closest_oriented(points: torch.Tensor, normals: torch.Tensor, surface: DeviceSurface, min_dot: float = 0.0, k: int = DEVICE_CANDIDATES) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Nearest points of a template part whose face normal agrees with the query normal, searched on
    the device: the ``k`` admissible faces (``dot(face normal, query normal) > min_dot``) with the
    nearest centroids, then the exact closest point on each; a query with no admissible face at all
    takes the nearest of the ``k`` faces with the nearest centroids. The device counterpart of
    :meth:`proctex.geometry.surface.SurfaceIndex.query_oriented` with ``exact=False`` (the same
    admissibility, another candidate search: it can differ where a far face's centroid hides a near
    edge, measured in ``tests/test_cage_device.py``).

    Args:
        points: (q, 3) queries; normals: (q, 3) unit query normals (same device and dtype).

    Returns:
        ``(closest (q, 3), faces (q,) int64, barycentric (q, 3))``.
    """
    F = surface.tri.shape[0]
    k = int(min(k, F))
    out_p, out_f, out_b = [], [], []
    for s in range(0, points.shape[0], DEVICE_BLOCK):
        p, n = points[s : s + DEVICE_BLOCK], normals[s : s + DEVICE_BLOCK]
        d = torch.cdist(p, surface.centroids)  # (r, F)
        adm = (n @ surface.normals.T) > min_dot
        any_adm = adm.any(1, keepdim=True)
        cand = torch.topk(torch.where(adm | ~any_adm, d, torch.full_like(d, torch.inf)), k, dim=1, largest=False).indices  # (r, k)
        valid = adm.gather(1, cand) | ~any_adm
        cp, bary = closest_on_triangles(p[:, None, :], *surface.tri[cand].unbind(2))
        d2 = torch.where(valid, ((cp - p[:, None, :]) ** 2).sum(-1), torch.full_like(d[:, :k], torch.inf))
        best = d2.argmin(1, keepdim=True)
        out_p.append(cp.gather(1, best[..., None].expand(-1, 1, 3))[:, 0])
        out_f.append(cand.gather(1, best)[:, 0])
        out_b.append(bary.gather(1, best[..., None].expand(-1, 1, 3))[:, 0])
    return torch.cat(out_p), torch.cat(out_f), torch.cat(out_b)


def oriented_nn(points: torch.Tensor, point_normals: torch.Tensor, query: torch.Tensor, query_normals: torch.Tensor, k: int = 8) -> torch.Tensor:
    """Per pair, index into ``points`` of each query's nearest point with an agreeing normal among
    its ``k`` nearest (else its plain nearest): :func:`proctex.correspond.cage._oriented_nn` for a
    batch of pairs at once, by exact distances on the device.

    Args:
        points, point_normals: (a, n, 3); query, query_normals: (a, m, 3).

    Returns:
        (a, m) int64 indices into each pair's ``points``.
    """
    a, n = points.shape[:2]
    k = int(min(k, n))
    rows = max(1, DEVICE_BLOCK * 1024 // max(n, 1))  # queries per block: about 8M distances
    out = []
    for s in range(0, query.shape[1], rows):
        q, qn = query[:, s : s + rows], query_normals[:, s : s + rows]
        nn = torch.topk(torch.cdist(q, points, compute_mode="donot_use_mm_for_euclid_dist"), k, dim=2, largest=False).indices  # (a, r, k), nearest first
        pn = point_normals.gather(1, nn.reshape(a, -1, 1).expand(-1, -1, 3)).reshape(*nn.shape, 3)
        ok = (pn * qn[:, :, None, :]).sum(-1) > 0
        first = torch.where(ok.any(2), ok.to(torch.int8).argmax(2), torch.zeros_like(nn[..., 0]))
        out.append(nn.gather(2, first[..., None])[..., 0])
    return torch.cat(out, 1)
