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
from .mvc import mean_value_coordinates
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
) -> list[CageResult]:
    """Solve every pair of ``problems`` onto the one ``template`` part; one :class:`CageResult` per
    problem, in order, each what :func:`solve_cage` returns for it alone (to float rounding of the
    batched products; ``seconds``: its bucket's wall time)."""
    cfg = (config or CageConfig()).validate()
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
        for i, res in zip(rows, _solve_bucket([problems[i] for i in rows], [cages[i] for i in rows], template, template_vertex_normals, cfg)):
            out[i] = res
    return out  # type: ignore[return-value]


def _solve_bucket(problems: list[CageProblem], cages: list[tuple[np.ndarray, np.ndarray]], template: SurfaceIndex, template_vertex_normals: np.ndarray, cfg: CageConfig) -> list[CageResult]:
    """One bucket's pairs (the same cage lattice and sample counts), with their initial cages."""
    t0 = time.perf_counter()
    device = torch.device(cfg.device if (cfg.device != "cuda" or torch.cuda.is_available()) else "cpu")
    dtype = torch.float64 if cfg.dtype == "float64" else torch.float32
    B = len(problems)
    n, m = len(problems[0].points), len(problems[0].template_samples)
    rngs = [np.random.default_rng(p.seed) for p in problems]
    cage_faces = cages[0][1]
    cage0 = np.stack([c[0] for c in cages])  # (B, V, 3)
    V = cage0.shape[1]
    W_pts = torch.stack([mean_value_coordinates(p.points, c, cage_faces) for p, (c, _) in zip(problems, cages)]).to(device, dtype)  # (B, n, V)
    k_max = max(len(p.tri_vertices) for p in problems)
    f_max = max(len(p.tri_faces) for p in problems)
    W_tri = torch.zeros(B, k_max, V, dtype=dtype, device=device)
    tf = torch.zeros(B, f_max, 3, dtype=torch.long, device=device)  # padding: face (0, 0, 0), never sampled
    for b, (p, (c, _)) in enumerate(zip(problems, cages)):
        W_tri[b, : len(p.tri_vertices)] = mean_value_coordinates(p.tri_vertices, c, cage_faces).to(device, dtype)
        tf[b, : len(p.tri_faces)] = torch.as_tensor(np.asarray(p.tri_faces, dtype=np.int64))
    tidx = torch.as_tensor(np.stack([np.asarray(p.tri_index, dtype=np.int64) for p in problems]), device=device)  # (B, n)
    faces_t = torch.as_tensor(cage_faces, device=device)
    C0 = torch.as_tensor(cage0, device=device, dtype=dtype)
    triples = torch.as_tensor(lattice_triples(cage0[0], cage_divisions(cage0[0].max(0) - cage0[0].min(0), cfg.level, cfg.elongation)), device=device)
    T_np = np.stack([p.template_samples for p in problems])  # (B, m, 3)
    Tn_np = np.stack([p.template_sample_normals for p in problems])
    T = torch.as_tensor(T_np, device=device, dtype=dtype)
    vn = np.asarray(template_vertex_normals, dtype=float)

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
        # Chamfer matches of every pair in one KD-tree: pair j shifted by j * shift along x.
        Ta, Tna = T_np[active].reshape(-1, 3), Tn_np[active].reshape(-1, 3)
        lo = min(float(xd.min()), float(Ta.min()))
        shift = 3.0 * max(float(xd.max()) - lo, float(Ta.max()) - lo, 1.0)
        xs, Ts = xd.copy(), Ta.copy()
        xs[:, 0] += np.repeat(np.arange(a) * shift, n)
        Ts[:, 0] += np.repeat(np.arange(a) * shift, m)
        bwd = _oriented_nn(cKDTree(xs), xs, nd, Ts, Tna)
        x_flat, n_flat = x.reshape(-1, 3), nrm.reshape(-1, 3)
        Tf = T[A].reshape(-1, 3)
        if cfg.chamfer == "plane":
            chamfer = (((Tf - x_flat[bwd]) * n_flat[bwd]).sum(-1) ** 2).reshape(a, m).mean(-1)
        else:
            fwd = _oriented_nn(cKDTree(Ts), Ts, Tna, xs, nd)
            chamfer = ((x_flat - Tf[fwd]) ** 2).sum(-1).reshape(a, n).mean(-1) + ((Tf - x_flat[bwd]) ** 2).sum(-1).reshape(a, m).mean(-1)
        if len(triples):
            smooth = ((off[:, triples[:, 0]] - 2 * off[:, triples[:, 1]] + off[:, triples[:, 2]]) ** 2).sum(-1).mean(-1)
        else:
            smooth = torch.zeros(a, device=device, dtype=dtype)
        rest = (off**2).sum(-1).mean(-1)
        loss = cfg.w_surface * surface + cfg.w_chamfer * chamfer + cfg.w_normal * normal + cfg.w_smooth * smooth + cfg.w_rest * rest
        values = loss.detach().cpu().numpy()
        for r, b in enumerate(active):  # the state each loss belongs to (before the step below)
            if values[r] < best_value[b]:
                best_value[b] = values[r]
                best_offset[b] = off[r].detach()
        total = loss.sum()
        if cfg.w_mvc > 0 and (it - 1) % max(cfg.mvc_every, 1) == 0:
            pen = []
            for r, b in enumerate(active):
                sub = rngs[b].choice(n, size=min(cfg.mvc_points, n), replace=False)
                Wd = mean_value_coordinates(x[r][torch.as_tensor(sub, device=device)], C[r], faces_t)
                pen.append(torch.relu(-Wd).sum(1).mean())
            mvc_rows = torch.stack(pen)
            mvc_term[A] = mvc_rows.detach()
            total = total + cfg.w_mvc * mvc_rows.sum()
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
        s, c, nm, sm, rs = (t.detach().cpu().numpy() for t in (surface, chamfer, normal, smooth, rest))
        for r, b in enumerate(active):
            histories[b].append(float(values[r]))
            terms[b] = {"surface": float(s[r]), "chamfer": float(c[r]), "normal": float(nm[r]), "smooth": float(sm[r]), "rest": float(rs[r]), "negative_mvc": float(mvc_term[b])}
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
