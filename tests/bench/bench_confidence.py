"""Does the teacher's confidence (:mod:`proctex.correspond.confidence`) point at its errors?

For built families with a ground truth (built-ins: canonical coordinates; the sofa export: vertex
index), every solved *train* cage pair is scored against the truth point by point (measuring
only: the build never sees it), and its per-point neighbour disagreement and loss weights are
computed exactly as training computes them (:func:`neighbour_disagreement` over the group's train
pairs, :func:`confidence_weights`). Printed per family: the teacher's truth error (mean), the
rank correlation of disagreement with it (per point and per pair mean), and the teacher's error
as the weighted loss sees it (weighted mean) -- lower is a cleaner target for the student.

    python tests/bench/bench_confidence.py out/fidelity_default2/fork out/fidelity_real2/sofa
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def teacher_errors(path: str) -> dict[int, list[tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    """Per group, per train pair with a truth: ``(src, dst, truth error (n,))``."""
    from proctex.geometry.parts import part_mesh, segment
    from proctex.geometry.surface import SurfaceIndex, interpolate
    from proctex.measure.fidelity import template_truth
    from proctex.store.layout import FamilyStore
    from proctex.store.samples import load_sample, read_pair, samples
    from proctex.store.state import stored_config
    from proctex.store.template import load_template_shape
    from proctex.transfer.assets import load_assets
    from proctex.transfer.assign import assign_parts, choose_part, representative_part

    store = FamilyStore(path)
    config = stored_config(store)
    assets = load_assets(store)
    template = load_template_shape(store, config)
    kind = "vertex-index" if config.truth == "vertex-index" else "canonical"
    truth = template_truth(template, assets.grouping, assets, kind)
    rows = {r["id"]: r for r in samples(store)}
    done = [r for r in store.read_table("pairs.parquet").to_pylist() if r["status"] == "done" and r["split"] == "train"]
    shapes: dict[str, tuple] = {}
    out: dict[int, list] = {}
    for rec in sorted(done, key=lambda r: (r["group"], r["id"])):
        g, sid = int(rec["group"]), rec["id"]
        src, dst = (a.astype(np.float64) for a in read_pair(store, sid, g))
        if sid not in shapes:
            shape = load_sample(store, rows[sid], config)
            seg = segment(shape)
            shapes[sid] = (shape, seg, assign_parts(shape, seg, assets))
        shape, seg, assignment = shapes[sid]
        a = choose_part(assignment, g)
        part = seg.parts[a.part]
        vn, f = representative_part(*part_mesh(shape, part), a)
        hit = SurfaceIndex(vn, f).query(src)
        if kind == "vertex-index":
            ids = part.vertices[f[hit.faces]]
            if (truth.vertex_group[ids] != g).any():
                continue
            true = np.einsum("kj,kjd->kd", hit.bary, truth.vertex_point[ids])
        else:
            if g not in truth.label_groups.get(part.label, ()):
                continue
            th = truth.rep_canonical[g].query(interpolate(shape.canonical[part.vertices], f, hit.faces, hit.bary))
            ga = assets.groups[g]
            true = interpolate(ga.vertices, ga.faces, th.faces, th.bary)
        out.setdefault(g, []).append((src, dst, np.linalg.norm(dst - true, axis=1), json.loads(rows[sid]["params"] or "{}")))
    return out


def measure(path: str, k: int, scale: float, neighbours: str) -> dict:
    from scipy.stats import spearmanr

    from proctex.correspond.confidence import (
        confidence_weights,
        neighbour_disagreement,
        param_features,
    )

    errs, dis, wts, pe, pd = [], [], [], [], []
    for pairs in teacher_errors(path).values():
        feats = param_features([p for *_, p in pairs]) if neighbours == "params" else None
        d = neighbour_disagreement([(s, t) for s, t, _, _ in pairs], k=k, features=feats)
        w = confidence_weights(d, scale=scale)
        for (_, _, e, _), di, wi in zip(pairs, d, w):
            errs.append(e), dis.append(di), wts.append(wi), pe.append(e.mean()), pd.append(di.mean())
    e, d, w = np.concatenate(errs), np.concatenate(dis), np.concatenate(wts)
    return {
        "family": Path(path).name,
        "pairs": len(pe),
        "teacher_gt_mean": float(e.mean()),
        "spearman_point": float(spearmanr(e, d)[0]),
        "spearman_pair": float(spearmanr(pe, pd)[0]),
        "weighted_gt_mean": float((w * e).sum() / w.sum()),
        "weight_mean": float(w.mean()),
    }


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("stores", nargs="+", help="built family folders with a truth")
    ap.add_argument("--k", type=int, default=3)
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--neighbours", choices=["params", "shape"], default="params", help="neighbours by procedural parameters (where every shape has them) or by shape")
    ap.add_argument("--out", default=None, help="JSON report")
    args = ap.parse_args(argv)
    rows = [measure(s, args.k, args.scale, args.neighbours) for s in args.stores]
    print("| family | train pairs | teacher GT mean | Spearman (point / pair) | weighted GT mean | mean weight |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['family']} | {r['pairs']} | {r['teacher_gt_mean']:.4f} | {r['spearman_point']:.2f} / {r['spearman_pair']:.2f} | {r['weighted_gt_mean']:.4f} | {r['weight_mean']:.2f} |", flush=True
        )
    if args.out:
        Path(args.out).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    sys.exit(main())
