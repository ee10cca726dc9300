"""Evaluate a built family on its unseen shapes (DESIGN §6): the ``evaluate`` build stage.

For every test shape (the folder's inference split, or the model's held-out samples) and every
mapper (``corrnet`` = the family's ProcCorrNets, the run-time path; ``identity`` and ``nearest`` as
baselines):

- **transfer** (:func:`proctex.transfer.transfer`) and GLB encoding, timed per shape;
- **bake** (:func:`proctex.transfer.bake`) into the shape's own atlas;
- **coverage** (:func:`proctex.metrics.coverage`) of both the real-time output (template textures
  through the transferred UVs) and the baked one;
- the colours the shape shows at points tracked from the template, for the **tracked-point
  texture variance** across shapes (from the baked textures, as DESIGN §6 defines it, and through
  the real-time UVs).

For ProcCorrNet also, on the stored cage pairs of the test shapes (``pairs`` stage):

- **pseudo-ground-truth error** (network prediction vs cage correspondence in the template part's
  normalised frame): ``mean`` over (shape, group) pairs of the pair's mean point error, ``max`` the
  largest pair mean (the paper's "max"), ``max_point`` the largest point error;
- for built-in models (canonical coordinates), the **ground-truth error** of the network (its
  prediction projected onto the template surface) next to the cage solver's, on the same points.

Results go to ``metrics.json`` in the store, in the shape ``{"methods": {"corrnet": {...}, ...}}``.
"""

from __future__ import annotations

import time
from typing import Any, Callable, Sequence

import numpy as np

from .store import FamilyStore

METHODS = ("corrnet", "identity", "nearest")


def _summary(values: Sequence[float]) -> dict[str, float]:
    v = np.asarray(values, dtype=float)
    if not len(v):
        return {}
    return {"mean": float(v.mean()), "median": float(np.median(v)), "max": float(v.max()), "min": float(v.min())}


def _mapper(name: str, store: FamilyStore, assets) -> Any:
    from .family import load_models
    from .transfer import IdentityMapper, NetworkMapper, SolverMapper

    if name == "corrnet":
        models = load_models(store)
        if not models:
            raise ValueError(f"{store.uri}: no trained models (run the train stage)")
        return NetworkMapper(models)
    if name == "identity":
        return IdentityMapper()
    if name == "nearest":
        return SolverMapper(assets, "nearest")
    raise ValueError(f"unknown method {name!r}; known: {', '.join(METHODS)}")


def pair_errors(store: FamilyStore, config, rows: list[dict[str, Any]], seed: int = 0, log: Callable[[str], None] = print) -> dict[str, Any]:
    """Pseudo-ground-truth error of the family's networks on the stored cage pairs of ``rows`` (test
    samples), and ground-truth errors of network and cage where the shapes carry canonical coordinates.

    Returns ``{"pgt": {...}, "gt": {...} | None, "cage_gt": {...} | None, "per_group": {g: {...}}}``.
    """
    from .corrnet import predict, sample_indices
    from .family import choose_part, load_assets, load_models, load_sample, read_pair, load_template_shape
    from .geometry import SurfaceIndex, normalised_frame
    from .metrics import gt_correspondence_error, interpolate
    from .parts import analyse, part_mesh, segment
    from .transfer import assign_parts

    models = load_models(store)
    pairs = [r for r in store.read_table("pairs.parquet").to_pylist() if r["status"] == "done"] if store.exists("pairs.parquet") else []
    ids = {r["id"] for r in rows}
    pairs = [p for p in pairs if p["id"] in ids and p["group"] in models]
    assets = load_assets(store)
    template = load_template_shape(store, config)
    tgrouping = analyse(template, seed=config.seed)
    by_id = {r["id"]: r for r in rows}
    rng = np.random.default_rng(seed)
    per_pair: list[dict[str, Any]] = []
    shape_cache: dict[str, Any] = {}
    for p in pairs:
        g = p["group"]
        model = models[g]
        src, dst, face = read_pair(store, p["id"], g, faces=True)
        src, dst = src.astype(np.float64), dst.astype(np.float64)
        ctx = src[sample_indices(len(src), model.context_points, rng)]
        pred = predict(model, ctx, src)
        err = np.linalg.norm(pred - dst, axis=1)
        rec = {"id": p["id"], "group": g, "pgt_mean": float(err.mean()), "pgt_max_point": float(err.max())}
        if p["id"] not in shape_cache:
            shape = load_sample(store, by_id[p["id"]], config)
            seg = segment(shape)
            shape_cache = {p["id"]: (shape, seg, assign_parts(shape, seg, assets))}
        shape, seg, assignment = shape_cache[p["id"]]
        a = choose_part(assignment, g)
        if a is not None and a.part == p["part"]:
            part = seg.parts[a.part]
            v, f = part_mesh(shape, part)
            c, r = normalised_frame(v)
            vn = (v - c) / (r if r > 0 else 1.0) @ a.R.T
            hit = SurfaceIndex(vn, f).query(src)
            # The run-time shortcut: predict at the part's vertices only and interpolate inside faces.
            at_vertices = interpolate(predict(model, ctx, vn), f, hit.faces, hit.bary)
            rec["pgt_vertex_mean"] = float(np.linalg.norm(at_vertices - dst, axis=1).mean())
            rec["shortcut_gap"] = float(np.linalg.norm(at_vertices - pred, axis=1).mean())
            ga = assets.groups[g]
            rep = tgrouping.parts[ga.rep]
            if not config.folder and shape.canonical is not None and template.canonical is not None:
                # Built-in model: canonical coordinates give the ground truth.
                src_can = interpolate(shape.canonical[part.vertices], f, hit.faces, hit.bary)
                tcan = template.canonical[rep.vertices]
                proj = ga.index.query(pred)
                net = gt_correspondence_error(src_can, proj.points, proj.faces, ga.vertices, ga.faces, tcan)
                cage = gt_correspondence_error(src_can, dst, face, ga.vertices, ga.faces, tcan)
                rec.update(gt_mean=net.mean, gt_p95=net.p95, gt_max=net.max, cage_gt_mean=cage.mean, cage_gt_p95=cage.p95, cage_gt_max=cage.max)
        per_pair.append(rec)
    out: dict[str, Any] = {"pairs": len(per_pair)}
    if not per_pair:
        return out
    means = [r["pgt_mean"] for r in per_pair]
    out["pgt"] = {"mean": float(np.mean(means)), "max": float(np.max(means)), "max_point": float(max(r["pgt_max_point"] for r in per_pair))}
    located = [r for r in per_pair if "pgt_vertex_mean" in r]
    if located:  # the vertex shortcut against per-point prediction, on the same pairs
        out["pgt_vertex_shortcut"] = {"mean": float(np.mean([r["pgt_vertex_mean"] for r in located])), "max": float(np.max([r["pgt_vertex_mean"] for r in located])),
                                      "per_point_mean": float(np.mean([r["pgt_mean"] for r in located])), "gap": float(np.mean([r["shortcut_gap"] for r in located])),
                                      "pairs": len(located)}
    gt = [r for r in per_pair if "gt_mean" in r]
    if gt:
        out["gt"] = {"mean": float(np.mean([r["gt_mean"] for r in gt])), "p95": float(np.mean([r["gt_p95"] for r in gt])), "max": float(max(r["gt_max"] for r in gt))}
        out["cage_gt"] = {"mean": float(np.mean([r["cage_gt_mean"] for r in gt])), "p95": float(np.mean([r["cage_gt_p95"] for r in gt])), "max": float(max(r["cage_gt_max"] for r in gt))}
    groups: dict[str, Any] = {}
    for g in sorted({r["group"] for r in per_pair}):
        sel = [r for r in per_pair if r["group"] == g]
        entry = {"pairs": len(sel), "pgt_mean": float(np.mean([r["pgt_mean"] for r in sel])), "pgt_max": float(np.max([r["pgt_mean"] for r in sel]))}
        if sel and "gt_mean" in sel[0]:
            entry["gt_mean"] = float(np.mean([r.get("gt_mean", np.nan) for r in sel]))
            entry["cage_gt_mean"] = float(np.mean([r.get("cage_gt_mean", np.nan) for r in sel]))
        groups[str(g)] = entry
    out["per_group"] = groups
    log(f"evaluate: pseudo-ground-truth error mean {out['pgt']['mean']:.4f} max {out['pgt']['max']:.4f} over {len(per_pair)} pairs"
        + (f"; ground truth net {out['gt']['mean']:.4f} vs cage {out['cage_gt']['mean']:.4f}" if gt else ""))
    return out


def evaluate(
    store: FamilyStore,
    methods: Sequence[str] = ("corrnet",),
    split: str = "test",
    limit: int | None = None,
    bake_size: int = 512,
    view_size: int = 256,
    tracked: int = 5000,
    seed: int = 0,
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Evaluate the family in ``store`` (module docstring); returns the metrics dict (not written).

    Args:
        methods: mappers to compare (:data:`METHODS`).
        split: which samples ("test": the unseen shapes; "train").
        limit: evaluate at most this many shapes (the first ones).
        bake_size: baked texture size; view_size: coverage render size; tracked: tracked points.
    """
    from .family import load_assets, load_sample, samples, stored_config, up_axis
    from .metrics import coverage
    from .transfer import bake, glb, shape_colours_at_template_points, tracked_points, tracked_variance, transfer

    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        raise ValueError(f"methods must be a non-empty subset of {', '.join(METHODS)}, got {list(methods)}")
    if split not in ("train", "test"):
        raise ValueError(f"split must be train or test, got {split!r}")
    config = stored_config(store)
    rows = [r for r in samples(store) if r["split"] == split][: limit if limit is not None else None]
    if len(rows) < 2:
        raise ValueError(f"{store.uri}: evaluation needs at least two {split} shapes, found {len(rows)}")
    assets = load_assets(store)
    painted = assets.painted
    up = up_axis(config)
    points = tracked_points(assets, n=tracked, seed=seed)
    shapes = [load_sample(store, r, config) for r in rows]
    metrics: dict[str, Any] = {"split": split, "shapes": len(rows), "ids": [r["id"] for r in rows], "methods": {}}
    for name in methods:
        mapper = _mapper(name, store, assets)
        secs, bake_secs, cov, cov_baked, cols, cols_baked, per_shape = [], [], [], [], [], [], []
        t0 = time.perf_counter()
        for row, shape in zip(rows, shapes):
            t = time.perf_counter()
            result = transfer(shape, assets, mapper, seed=seed)
            glb(shape, result, assets)
            secs.append(time.perf_counter() - t)
            baked = bake(shape, result, assets, size=bake_size)
            bake_secs.append(baked.seconds)
            masks = list(painted) + [np.ones(t.shape[:2], bool) for t in result.new_textures]
            c1 = coverage(shape.vertices, shape.faces, result.corner_uv, result.face_group, masks, up=up, size=view_size).share
            c2 = coverage(shape.vertices, shape.faces, baked.corner_uv, baked.face_group, baked.painted, up=up, size=view_size).share
            cov.append(c1)
            cov_baked.append(c2)
            cols.append(shape_colours_at_template_points(shape, result, assets, points))
            cols_baked.append(shape_colours_at_template_points(shape, result, assets, points, baked.textures, baked.corner_uv, baked.face_group))
            per_shape.append({"id": row["id"], "seconds": secs[-1], "bake_seconds": bake_secs[-1], "coverage": c1, "coverage_baked": c2,
                              "parts": len(result.assignment), "notes": list(result.notes)})
        tv = tracked_variance(cols)
        tvb = tracked_variance(cols_baked)
        entry = {
            # DESIGN §6: colours from each shape's own baked texture; also through the real-time UVs.
            "tracked_point_variance": tvb.value,
            "tracked_point_variance_realtime": tv.value,
            "tracked_point_variance_per_group": tvb.to_dict()["per_group"],
            "coverage": float(max(cov)),
            "coverage_mean": float(np.mean(cov)),
            "coverage_baked": float(max(cov_baked)),
            "shapes_with_holes": int(sum(c > 0 for c in cov)),
            "seconds_per_shape": float(np.median(secs)),
            "seconds": _summary(secs),
            "bake_seconds": _summary(bake_secs),
            "per_shape": per_shape,
        }
        if name == "corrnet":
            entry.update(pair_errors(store, config, rows, seed=seed, log=log))
        metrics["methods"][name] = entry
        log(f"evaluate {name}: {len(rows)} shapes in {time.perf_counter() - t0:.0f}s: tracked variance {tvb.value:.4f} "
            f"(real-time UVs {tv.value:.4f}), coverage max {max(cov):.4f} (baked {max(cov_baked):.4f}), "
            f"{1000 * float(np.median(secs)):.0f} ms per shape")
    return metrics


def markdown_table(metrics: dict[str, Any]) -> str:
    """A Markdown table of :func:`evaluate`'s metrics, one row per method."""
    def f(x: Any, nd: int = 4) -> str:
        return "-" if x is None else f"{x:.{nd}f}"

    lines = [f"{metrics['shapes']} {metrics['split']} shapes", "",
             "| method | tracked-point variance (baked / real-time) | coverage (max) | pseudo-GT error mean / max | GT error mean (cage) | ms per shape |",
             "|---|---|---|---|---|---|"]
    for name, m in metrics["methods"].items():
        pgt = m.get("pgt") or {}
        gt = m.get("gt")
        lines.append(
            f"| {name} | {f(m['tracked_point_variance'])} / {f(m['tracked_point_variance_realtime'])} | {f(m['coverage'])} | "
            f"{f(pgt.get('mean'))} / {f(pgt.get('max'))} | "
            + (f"{f(gt['mean'])} ({f(m['cage_gt']['mean'])})" if gt else "-")
            + f" | {1000 * m['seconds_per_shape']:.0f} |"
        )
    return "\n".join(lines)


def stage_evaluate(store: FamilyStore, config, log: Callable[[str], None] = print, methods: Sequence[str] = ("corrnet", "identity")) -> None:
    """The ``evaluate`` build stage: :func:`evaluate` on the test shapes into ``metrics.json``."""
    from .family import _mark, samples, stage_done

    if stage_done(store, "evaluate"):
        log("evaluate: done already")
        return
    if sum(r["split"] == "test" for r in samples(store)) < 2:
        log("evaluate: fewer than two test shapes, skipped")
        return
    metrics = evaluate(store, methods=methods, log=log)
    store.write_json("metrics.json", metrics)
    net = metrics["methods"]["corrnet"]
    _mark(store, "evaluate", shapes=metrics["shapes"], tracked_point_variance=net["tracked_point_variance"], coverage=net["coverage"],
          pgt=net.get("pgt", {}), gt=net.get("gt"), cage_gt=net.get("cage_gt"), seconds_per_shape=net["seconds_per_shape"])
