"""Evaluate a built family on its unseen shapes (DESIGN §6): ``proctex eval`` and the ``evaluate``
build stage.

Methods, side by side on the same shapes: ``corrnet`` (ProcTex's run-time path: parts with the
template representative's exact connectivity take its UVs, the family's ProcCorrNets map the rest),
``corrnet_all`` (the networks on every part), ``cage`` (the cage solver per part at transfer time:
the pseudo-ground truth), ``nearest`` (nearest surface point after similarity alignment), ``cpd``
(non-rigid Coherent Point Drift) and ``identity``. Every method but ``corrnet`` maps every part.

Per test shape (the folder's inference split, or the model's held-out samples) and method:

- **transfer** (:func:`proctex.transfer.transfer`) and GLB encoding, timed per shape;
- **bake** (:func:`proctex.transfer.bake`) into the shape's own atlas;
- **coverage** (:func:`proctex.metrics.coverage`) of both the real-time output (template textures
  through the transferred UVs) and the baked one;
- the colours the shape shows at points tracked from the template, for the **tracked-point
  texture variance** across shapes (from the baked textures, as DESIGN §6 defines it, and through
  the real-time UVs);
- **view similarity**: SSIM and PSNR (and LPIPS with a local weights file) between the template's
  and the shape's renders from the six canonical views.

On the stored cage pairs of the test shapes (``pairs`` stage), :func:`pair_errors`:

- **pseudo-ground-truth error** (prediction vs cage correspondence in the template part's
  normalised frame): ``mean`` over (shape, group) pairs of the pair's mean point error, ``max`` the
  largest pair mean (the paper's "max"), ``max_point`` the largest point error;
- for built-in models (canonical coordinates), the **ground-truth error** of every method on the
  same source points.

Shapes can be evaluated in parallel processes (``workers``). Results go to ``metrics.json`` in the
store, in the shape ``{"methods": {"corrnet": {...}, "cage": {...}, ...}}``.
"""

from __future__ import annotations

import time
from typing import Any, Callable, Sequence

import numpy as np

from .store import FamilyStore

METHODS = ("corrnet", "corrnet_all", "cage", "nearest", "cpd", "identity")
#: What ``proctex eval`` compares by default: ProcCorrNet and the three solvers of DESIGN §6.
DEFAULT_METHODS = ("corrnet", "corrnet_all", "cage", "nearest", "cpd")
#: ``corrnet`` is ProcTex's run-time path: parts with the template representative's exact
#: connectivity take its UVs directly, the network maps the rest. Every other method maps every part
#: (``corrnet_all``: the network on every part), as a transfer without ProcTex would.
SHORTCUT = {"corrnet"}


def _summary(values: Sequence[float]) -> dict[str, float]:
    v = np.asarray(values, dtype=float)
    if not len(v):
        return {}
    return {"mean": float(v.mean()), "median": float(np.median(v)), "max": float(v.max()), "min": float(v.min())}


def _mapper(name: str, store: FamilyStore, assets, config=None) -> Any:
    from .family import load_models
    from .transfer import IdentityMapper, NetworkMapper, SolverMapper

    if name in ("corrnet", "corrnet_all"):
        models = load_models(store)
        if not models:
            raise ValueError(f"{store.uri}: no trained models (run the train stage)")
        return NetworkMapper(models)
    if name == "identity":
        return IdentityMapper()
    if name in ("cage", "nearest", "cpd"):  # solved per part at transfer time, as the build solves its pairs
        return SolverMapper(assets, name, n_points=config.corr_points if config is not None else 2000, cage=_cage_config(config))
    raise ValueError(f"unknown method {name!r}; known: {', '.join(METHODS)}")


def _cage_config(config) -> Any:
    if config is None:
        return None
    from .cage import CageConfig

    return CageConfig(level=config.cage_level, iterations=config.cage_iterations).validate()  # as the build's pairs


def pair_errors(store: FamilyStore, config, rows: list[dict[str, Any]], methods: Sequence[str] = ("corrnet",), seed: int = 0,
                log: Callable[[str], None] = print, assets=None) -> dict[str, Any]:
    """Errors on the stored cage pairs of ``rows`` (test samples).

    ProcCorrNet (``corrnet`` in ``methods``): pseudo-ground-truth error (prediction vs cage), the
    vertex shortcut's error and gap, per group. For built-in models (canonical coordinates) the
    ground-truth error of every method in ``methods`` on the same source points: the network, the
    stored cage solution, and ``nearest`` / ``cpd`` solved on the pair's part (their
    pseudo-ground-truth error too). ``assets``: the family's loaded template assets, if at hand.

    Returns ``{"pairs", "pgt", "pgt_vertex_shortcut", "gt", "cage_gt", "per_group", "methods": {m: {"pgt", "gt"}}}``
    (the unprefixed keys are ProcCorrNet's).
    """
    from .corrnet import predict, sample_indices
    from .family import choose_part, load_assets, load_models, load_sample, read_pair, load_template_shape
    from .geometry import SurfaceIndex, normalised_frame
    from .metrics import gt_correspondence_error, interpolate
    from .parts import analyse, part_mesh, segment
    from .transfer import SolverMapper, assign_parts

    models = load_models(store) if "corrnet" in methods else {}
    pairs = [r for r in store.read_table("pairs.parquet").to_pylist() if r["status"] == "done"] if store.exists("pairs.parquet") else []
    ids = {r["id"] for r in rows}
    pairs = [p for p in pairs if p["id"] in ids]
    assets = assets if assets is not None else load_assets(store)
    template = load_template_shape(store, config)
    tgrouping = analyse(template, seed=config.seed)
    by_id = {r["id"]: r for r in rows}
    canonical = not config.folder and template.canonical is not None
    solvers = {m: SolverMapper(assets, m, n_points=config.corr_points) for m in methods if m in ("nearest", "cpd")} if canonical else {}
    rng = np.random.default_rng(seed)
    per_pair: list[dict[str, Any]] = []
    shape_cache: dict[str, Any] = {}
    for p in pairs:
        g = p["group"]
        src, dst, face = read_pair(store, p["id"], g, faces=True)
        src, dst = src.astype(np.float64), dst.astype(np.float64)
        rec: dict[str, Any] = {"id": p["id"], "group": g}
        preds: dict[str, np.ndarray] = {}
        model = models.get(g)
        if model is not None:
            ctx = src[sample_indices(len(src), model.context_points, rng)]
            preds["corrnet"] = predict(model, ctx, src)
        if p["id"] not in shape_cache:
            shape = load_sample(store, by_id[p["id"]], config)
            seg = segment(shape)
            shape_cache = {p["id"]: (shape, seg, assign_parts(shape, seg, assets))}
        shape, seg, assignment = shape_cache[p["id"]]
        a = choose_part(assignment, g)
        located = a is not None and a.part == p["part"]
        if located:
            part = seg.parts[a.part]
            v, f = part_mesh(shape, part)
            c, r = normalised_frame(v)
            vn = (v - c) / (r if r > 0 else 1.0) @ a.R.T
            hit = SurfaceIndex(vn, f).query(src)
            if model is not None:
                # The run-time shortcut: predict at the part's vertices only and interpolate inside faces.
                at_vertices = interpolate(predict(model, ctx, vn), f, hit.faces, hit.bary)
                rec["pgt_vertex_mean"] = float(np.linalg.norm(at_vertices - dst, axis=1).mean())
                rec["shortcut_gap"] = float(np.linalg.norm(at_vertices - preds["corrnet"], axis=1).mean())
            for m, solver in solvers.items():  # the baselines on the same part and the same points
                preds[m] = solver.map(g, vn, f, src, seed=seed)
        for m, pred in preds.items():
            err = np.linalg.norm(pred - dst, axis=1)
            rec[f"{m}_pgt_mean"], rec[f"{m}_pgt_max_point"] = float(err.mean()), float(err.max())
        if located and canonical and shape.canonical is not None:
            ga = assets.groups[g]
            src_can = interpolate(shape.canonical[part.vertices], f, hit.faces, hit.bary)
            tcan = template.canonical[tgrouping.parts[ga.rep].vertices]
            for m, pred in [*preds.items(), ("cage", None)]:
                if pred is None:
                    e = gt_correspondence_error(src_can, dst, face, ga.vertices, ga.faces, tcan)
                else:
                    proj = ga.index.query(pred)
                    e = gt_correspondence_error(src_can, proj.points, proj.faces, ga.vertices, ga.faces, tcan)
                rec[f"{m}_gt_mean"], rec[f"{m}_gt_p95"], rec[f"{m}_gt_max"] = e.mean, e.p95, e.max
        per_pair.append(rec)
    out: dict[str, Any] = {"pairs": len(per_pair), "methods": {}}

    def stats(m: str) -> dict[str, Any]:
        got: dict[str, Any] = {}
        sel = [r for r in per_pair if f"{m}_pgt_mean" in r]
        if sel:
            means = [r[f"{m}_pgt_mean"] for r in sel]
            got["pgt"] = {"mean": float(np.mean(means)), "max": float(np.max(means)),
                          "max_point": float(max(r[f"{m}_pgt_max_point"] for r in sel)), "pairs": len(sel)}
        sel = [r for r in per_pair if f"{m}_gt_mean" in r]
        if sel:
            got["gt"] = {"mean": float(np.mean([r[f"{m}_gt_mean"] for r in sel])), "p95": float(np.mean([r[f"{m}_gt_p95"] for r in sel])),
                         "max": float(max(r[f"{m}_gt_max"] for r in sel)), "pairs": len(sel)}
        return got

    for m in [*methods, "cage"]:
        if m != "identity":
            out["methods"][m] = stats(m)
    net = out["methods"].get("corrnet", {})
    if "pgt" in net:
        out["pgt"] = net["pgt"]
    located = [r for r in per_pair if "pgt_vertex_mean" in r]
    if located:  # the vertex shortcut against per-point prediction, on the same pairs
        out["pgt_vertex_shortcut"] = {"mean": float(np.mean([r["pgt_vertex_mean"] for r in located])), "max": float(np.max([r["pgt_vertex_mean"] for r in located])),
                                      "per_point_mean": float(np.mean([r["corrnet_pgt_mean"] for r in located])), "gap": float(np.mean([r["shortcut_gap"] for r in located])),
                                      "pairs": len(located)}
    if "gt" in net:
        out["gt"], out["cage_gt"] = net["gt"], out["methods"]["cage"].get("gt")
    groups: dict[str, Any] = {}
    for g in sorted({r["group"] for r in per_pair if "corrnet_pgt_mean" in r}):
        sel = [r for r in per_pair if r["group"] == g and "corrnet_pgt_mean" in r]
        entry = {"pairs": len(sel), "pgt_mean": float(np.mean([r["corrnet_pgt_mean"] for r in sel])), "pgt_max": float(np.max([r["corrnet_pgt_mean"] for r in sel]))}
        if "corrnet_gt_mean" in sel[0]:
            entry["gt_mean"] = float(np.mean([r.get("corrnet_gt_mean", np.nan) for r in sel]))
            entry["cage_gt_mean"] = float(np.mean([r.get("cage_gt_mean", np.nan) for r in sel]))
        groups[str(g)] = entry
    out["per_group"] = groups
    if "pgt" in out:
        log(f"evaluate: pseudo-ground-truth error mean {out['pgt']['mean']:.4f} max {out['pgt']['max']:.4f} over {out['pgt']['pairs']} pairs"
            + (f"; ground truth net {out['gt']['mean']:.4f} vs cage {out['cage_gt']['mean']:.4f}" if "gt" in out else ""))
    return out


class _Context:
    """What evaluating one shape needs, loaded once per process: assets, tracked points, the
    template's reference views, mappers by name, settings."""

    def __init__(self, uri: str, settings: dict[str, Any]) -> None:
        from .family import load_assets, stored_config, up_axis
        from .render import render_six_views
        from .transfer import IdentityMapper, tracked_points, transfer

        self.store = FamilyStore(uri)
        self.config = stored_config(self.store)
        self.settings = settings
        self.assets = load_assets(self.store)
        self.up = up_axis(self.config)
        self.points = tracked_points(self.assets, n=settings["tracked"], seed=settings["seed"])
        self.lpips = None
        if settings.get("lpips"):
            from .lpips import LPIPS

            self.lpips = LPIPS.load(settings["lpips"])
        # The template's own six views: what every transferred shape is compared with (DESIGN §6).
        tpl = transfer(self.assets.shape, self.assets, IdentityMapper(), seed=settings["seed"])
        self.reference, _ = render_six_views(self.assets.shape.vertices, self.assets.shape.faces, tpl.corner_uv, tpl.face_group,
                                             self.assets.textures, self.up, settings["view_size"])
        self.mappers: dict[str, Any] = {}

    def mapper(self, name: str) -> Any:
        if name not in self.mappers:
            self.mappers[name] = _mapper(name, self.store, self.assets, self.config)
        return self.mappers[name]


def evaluate_shape(ctx: _Context, name: str, row: dict[str, Any]) -> dict[str, Any]:
    """One shape with one method: transfer (timed, GLB included), bake, coverage of both, colours at
    the tracked points (real-time and baked), and view similarity with the template."""
    from .family import load_sample
    from .metrics import coverage, view_similarity
    from .render import render_six_views
    from .transfer import bake, glb, shape_colours_at_template_points, transfer

    st, assets, up = ctx.settings, ctx.assets, ctx.up
    shape = load_sample(ctx.store, row, ctx.config)
    t = time.perf_counter()
    result = transfer(shape, assets, ctx.mapper(name), seed=st["seed"], shortcut=name in SHORTCUT)
    glb(shape, result, assets, up=up)
    seconds = time.perf_counter() - t
    baked = bake(shape, result, assets, size=st["bake_size"])
    masks = list(assets.painted) + [np.ones(x.shape[:2], bool) for x in result.new_textures]
    c1 = coverage(shape.vertices, shape.faces, result.corner_uv, result.face_group, masks, up=up, size=st["view_size"]).share
    c2 = coverage(shape.vertices, shape.faces, baked.corner_uv, baked.face_group, baked.painted, up=up, size=st["view_size"]).share
    views, _ = render_six_views(shape.vertices, shape.faces, result.corner_uv, result.face_group,
                                list(assets.textures) + list(result.new_textures), up, st["view_size"])
    sim = view_similarity(ctx.reference, views, ctx.lpips)
    return {
        "colours": shape_colours_at_template_points(shape, result, assets, ctx.points),
        "colours_baked": shape_colours_at_template_points(shape, result, assets, ctx.points, baked.textures, baked.corner_uv, baked.face_group),
        "sim": sim,
        "record": {"id": row["id"], "seconds": seconds, "bake_seconds": baked.seconds, "coverage": c1, "coverage_baked": c2,
                   "ssim": sim.ssim, "psnr": sim.psnr, "lpips": sim.lpips, "parts": len(result.assignment),
                   "mapped_parts": len(result.assignment) - len(result.direct), "notes": list(result.notes)},
    }


_WORKER: dict[str, Any] = {}


def _init_worker(uri: str, settings: dict[str, Any]) -> None:
    import torch

    torch.set_num_threads(1)
    _WORKER["ctx"] = _Context(uri, settings)


def _work(job: tuple[str, dict[str, Any]]) -> dict[str, Any]:
    return evaluate_shape(_WORKER["ctx"], *job)


def evaluate(
    store: FamilyStore,
    methods: Sequence[str] = DEFAULT_METHODS,
    split: str = "test",
    limit: int | None = None,
    bake_size: int = 512,
    view_size: int = 256,
    tracked: int = 5000,
    seed: int = 0,
    lpips: str | None = None,
    workers: int = 1,
    log: Callable[[str], None] = print,
    quiet: bool = False,
) -> dict[str, Any]:
    """Evaluate the family in ``store`` (module docstring); returns the metrics dict (not written).

    Args:
        methods: mappers to compare (:data:`METHODS`).
        split: which samples ("test": the unseen shapes; "train").
        limit: evaluate at most this many shapes (the first ones).
        bake_size: baked texture size; view_size: coverage and view-similarity render size;
        tracked: tracked points; lpips: a local LPIPS weights file (:mod:`proctex.lpips`), optional.
        workers: processes evaluating shapes in parallel (1: this process).
        quiet: no progress lines.
    """
    from .family import samples, stored_config
    from .progress import Progress
    from .transfer import tracked_variance

    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        raise ValueError(f"methods must be a non-empty subset of {', '.join(METHODS)}, got {list(methods)}")
    if split not in ("train", "test"):
        raise ValueError(f"split must be train or test, got {split!r}")
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    config = stored_config(store)
    rows = [r for r in samples(store) if r["split"] == split][: limit if limit is not None else None]
    if len(rows) < 2:
        raise ValueError(f"{store.uri}: evaluation needs at least two {split} shapes, found {len(rows)}")
    if lpips:
        from .lpips import LPIPS

        LPIPS.load(lpips)  # a bad weights file fails before any work
    settings = {"bake_size": bake_size, "view_size": view_size, "tracked": tracked, "seed": seed, "lpips": lpips}

    metrics: dict[str, Any] = {"split": split, "shapes": len(rows), "ids": [r["id"] for r in rows], "lpips_weights": lpips,
                               "shortcut": sorted(SHORTCUT), "methods": {}}
    ctx = _Context(store.uri, settings) if workers == 1 else None
    pairs = pair_errors(store, config, rows, methods=list(dict.fromkeys(["corrnet" if m == "corrnet_all" else m for m in methods])), seed=seed,
                        log=log, assets=ctx.assets if ctx else None)
    pool = None
    if workers > 1:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        pool = ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"), initializer=_init_worker, initargs=(store.uri, settings))
    try:
        for name in methods:
            t0 = time.perf_counter()
            bar = Progress(f"evaluate {name}", len(rows), quiet=quiet)
            jobs = [(name, row) for row in rows]
            if pool:
                outs = []
                for out in pool.map(_work, jobs):
                    outs.append(out)
                    bar.update()
            else:
                outs = []
                for job in jobs:
                    outs.append(evaluate_shape(ctx, *job))
                    bar.update()
            per_shape = [o["record"] for o in outs]
            secs = [r["seconds"] for r in per_shape]
            cov = [r["coverage"] for r in per_shape]
            cov_baked = [r["coverage_baked"] for r in per_shape]
            sims = [o["sim"] for o in outs]
            tv = tracked_variance([o["colours"] for o in outs])
            tvb = tracked_variance([o["colours_baked"] for o in outs])
            entry = {
                # DESIGN §6: colours from each shape's own baked texture; also through the real-time UVs.
                "tracked_point_variance": tvb.value,
                "tracked_point_variance_realtime": tv.value,
                "tracked_point_variance_per_group": tvb.to_dict()["per_group"],
                "coverage": float(max(cov)),
                "coverage_mean": float(np.mean(cov)),
                "coverage_baked": float(max(cov_baked)),
                "shapes_with_holes": int(sum(c > 0 for c in cov)),
                # Renders of the template vs of each transferred shape, six canonical views.
                "ssim": float(np.mean([x.ssim for x in sims])),
                "psnr": float(np.mean([x.psnr for x in sims])),
                "lpips": float(np.mean([x.lpips for x in sims])) if lpips else None,
                "seconds_per_shape": float(np.median(secs)),
                "seconds": _summary(secs),
                "bake_seconds": _summary([r["bake_seconds"] for r in per_shape]),
                "mapped_parts": int(sum(r["mapped_parts"] for r in per_shape)),
                "per_shape": per_shape,
            }
            errors = pairs["methods"].get("corrnet" if name == "corrnet_all" else name, {})
            entry["pgt"], entry["gt"] = errors.get("pgt"), errors.get("gt")
            if name in ("corrnet", "corrnet_all"):
                entry.update({k: pairs[k] for k in ("pgt_vertex_shortcut", "cage_gt", "per_group") if k in pairs})
            if name == "cage":
                entry["pgt"] = {"mean": 0.0, "max": 0.0, "max_point": 0.0, "note": "the cage solution is the pseudo-ground truth"}
            metrics["methods"][name] = entry
            log(f"evaluate {name}: {len(rows)} shapes in {time.perf_counter() - t0:.0f}s: tracked variance {tvb.value:.4f} "
                f"(real-time UVs {tv.value:.4f}), coverage max {max(cov):.4f} (baked {max(cov_baked):.4f}), "
                f"SSIM {entry['ssim']:.3f}, PSNR {entry['psnr']:.1f} dB, {1000 * float(np.median(secs)):.0f} ms per shape")
    finally:
        if pool:
            pool.shutdown()
    metrics["pairs"] = pairs["pairs"]
    return metrics


def markdown_table(metrics: dict[str, Any]) -> str:
    """A Markdown table of :func:`evaluate`'s metrics, one row per method."""
    def f(x: Any, nd: int = 4) -> str:
        return "-" if x is None else f"{x:.{nd}f}"

    has_lpips = any(m.get("lpips") is not None for m in metrics["methods"].values())
    lines = [f"{metrics['shapes']} {metrics['split']} shapes", "",
             "| method | tracked-point variance (baked / real-time) | coverage (max) | SSIM | PSNR (dB) |" + (" LPIPS |" if has_lpips else "")
             + " pseudo-GT error mean / max | GT error mean | ms per shape |",
             "|---|---|---|---|---|" + ("---|" if has_lpips else "") + "---|---|---|"]
    for name, m in metrics["methods"].items():
        pgt = m.get("pgt") or {}
        gt = m.get("gt") or {}
        lines.append(
            f"| {name} | {f(m['tracked_point_variance'])} / {f(m['tracked_point_variance_realtime'])} | {f(m['coverage'])} | "
            f"{f(m.get('ssim'), 3)} | {f(m.get('psnr'), 1)} |" + (f" {f(m.get('lpips'), 3)} |" if has_lpips else "")
            + f" {f(pgt.get('mean'))} / {f(pgt.get('max'))} | {f(gt.get('mean'))} | {1000 * m['seconds_per_shape']:.0f} |"
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
    metrics = evaluate(store, methods=methods, log=log, quiet=True)
    store.write_json("metrics.json", metrics)
    net = metrics["methods"]["corrnet"]
    _mark(store, "evaluate", shapes=metrics["shapes"], tracked_point_variance=net["tracked_point_variance"], coverage=net["coverage"],
          pgt=net.get("pgt", {}), gt=net.get("gt"), cage_gt=net.get("cage_gt"), seconds_per_shape=net["seconds_per_shape"])
