"""Evaluate a built family on its unseen shapes (docs/results.md): ``proctex eval`` and the ``evaluate``
build stage.

Methods, side by side on the same shapes: ``corrnet`` (ProcTex's run-time path: parts with the
template representative's exact connectivity take its UVs, the rest is mapped by what the build
chose per group: its ProcCorrNet, the box map or the identity), ``corrnet_all`` (the networks on
every part), ``cage`` (the cage solver per part at transfer time),
``nearest`` (nearest surface point after similarity alignment), ``cpd`` (non-rigid Coherent Point
Drift) and ``identity`` (the normalised part frames taken to coincide, then projection). Every
method but ``corrnet`` maps every part.

Every figure reads each method's real output (its transfer, :func:`proctex.transfer.apply.transfer`) at
points located independently of it (:mod:`proctex.measure.fidelity`). Per test shape and method:

- **transfer** and GLB encoding, timed; **bake** into the shape's own atlas;
- **coverage** (:func:`proctex.texture.metrics.coverage`) of the real-time output and of the bake;
- the colours it shows at the **tracked points**, located by the family's tracker (``canonical``
  for built-in models, ``vertex-index`` when the samples share one vertex order, else ``cage``),
  through its real-time UVs and from its bake: the **tracked-point variance**;
- its **ground-truth error** at truth samples (when there is a truth) and its
  **pseudo-ground-truth error** at the stored cage pairs' points, both over all points (mean, p95,
  p99, max) and as the worst shape / pair mean;
- **view similarity**: SSIM and PSNR (and LPIPS with a local weights file) between the template's
  and the shape's renders from the six canonical views.

A method that fails a shape or drops a part is counted (untextured readings count as the colour
farthest from the template's, dropped points as :data:`proctex.measure.fidelity.FAIL_ERROR`), never
skipped. Shapes can be evaluated in parallel processes (``workers``). Results go to
``metrics.json`` in the store: ``{"tracker", "truth", "methods": {"corrnet": {...}, ...}}``.
"""

from __future__ import annotations

import time
from types import SimpleNamespace
from typing import Any, Callable, Sequence

import numpy as np

from proctex.geometry.parts import segment
from proctex.measure.fidelity import (
    Location,
    check_vertex_index,
    colours_at,
    error_summary,
    gt_errors,
    locate_by_map,
    locate_canonical,
    locate_vertex_index,
    pgt_errors,
    template_truth,
    tracked_points,
    tracked_variance,
    truth_samples,
)
from proctex.pools import process_pool
from proctex.progress import Progress
from proctex.sources.registry import source_kind
from proctex.sources.truthfiles import attach_file_truth, folder_truth, sample_mesh_paths
from proctex.store.config import TRUTHS
from proctex.store.layout import FamilyStore, StoreLayout
from proctex.store.looks import look_paint, resolve_look
from proctex.store.networks import load_models
from proctex.store.samples import load_sample, pair_seed, read_pair, read_pair_vertices, samples
from proctex.store.state import FamilyState, stored_config
from proctex.store.template import load_template_shape
from proctex.texture.lpips import LPIPS
from proctex.texture.metrics import coverage, view_similarity
from proctex.texture.painters import SurfacePainter
from proctex.texture.render import canonical_buffers, render_six_views
from proctex.transfer.apply import bake, shape_to_glb, transfer
from proctex.transfer.assets import load_assets
from proctex.transfer.assign import assign_parts
from proctex.transfer.mappers import IdentityMapper, SolverMapper
from proctex.transfer.methods import get_method, make_mapper, method_names, methods as registered_methods


def default_methods() -> tuple[str, ...]:
    """What ``proctex eval`` compares by default: every registered method that asks to be
    (:func:`proctex.transfer.methods.method_names`)."""
    return method_names(evaluate=True)


def shortcut_methods() -> set[str]:
    """The methods of ProcTex's run-time path (``corrnet``): parts with the template
    representative's exact connectivity take its UVs directly, the network maps the rest. Every other
    method maps every part (``corrnet_all``: the network on every part), as a transfer without ProcTex would."""
    return {m.name for m in registered_methods() if m.shortcut}


def _summary(values: Sequence[float]) -> dict[str, float]:
    v = np.asarray(values, dtype=float)
    if not len(v):
        return {}
    return {"mean": float(v.mean()), "median": float(np.median(v)), "max": float(v.max()), "min": float(v.min())}


def _cage_config(config) -> Any:
    return None if config is None else config.cage  # as the build's pairs


def _mapper(name: str, store: FamilyStore, assets, config=None) -> Any:
    method = get_method(name)
    models = load_models(store) if method.networks != "none" else None
    if method.networks == "required" and not models:
        raise ValueError(f"{store.uri}: no trained models (run the train stage)")
    # Solved per part at transfer time, as the build solves its pairs.
    return make_mapper(name, assets, models, corr_points=config.corr_points if config is not None else 2000, cage=_cage_config(config))


def labelled_grouping(grouping, shape):
    """``grouping`` (the build's, of ``shape`` without labels) with its parts labelled from ``shape``'s
    labels (a folder family's file truth); ``ValueError`` where ``shape`` does not split into the
    same parts (a template changed since the build)."""
    import dataclasses

    seg = segment(shape)
    old = grouping.segmentation
    if seg.n_parts != old.n_parts or any(not np.array_equal(a.vertices, b.vertices) for a, b in zip(seg.parts, old.parts)):
        raise ValueError("the template's parts are not the build's: the family changed since it was built")
    return dataclasses.replace(grouping, segmentation=seg)


def resolve_truth(config, truth: str = "auto") -> str | None:
    """The ground truth an evaluation uses: "canonical", "vertex-index" or None (no truth: the cage
    tracks points). ``truth`` (:data:`proctex.store.config.TRUTHS`) overrides the family config's."""
    if truth not in TRUTHS:
        raise ValueError(f"truth must be one of {', '.join(TRUTHS)}, got {truth!r}")
    t = config.truth if truth == "auto" else truth
    canonical = source_kind(config.source).canonical  # its shapes carry canonical coordinates
    if canonical and t in ("auto", "canonical") and config.source.blender:  # a .blend model's, where its tree was read
        canonical = bool(getattr(config.procedural_model(), "has_canonical", False))
    if not canonical and t in ("auto", "canonical") and config.source.folder:  # files with truth beside them
        canonical = folder_truth(config.source.folder)
    if t == "auto":
        return "canonical" if canonical else None
    if t == "none":
        return None
    if t == "canonical" and not canonical:
        raise ValueError(
            "canonical truth needs a built-in model family, a .blend model whose node tree could be read "
            "(canonical coordinates) or a folder whose every mesh file has a truth file beside it (<stem>.truth.npz)"
        )
    return t


def stored_pairs(store: FamilyStore, sid: str, index: list[dict[str, Any]] | None = None) -> list[dict[str, Any]]:
    """The solved cage pairs of sample ``sid``: ``[{"group", "part", "src", "dst"}]``; ``index``: the
    rows of ``pairs.parquet`` when already read."""
    if index is None:
        index = store.read_table(StoreLayout.PAIRS).to_pylist() if store.exists(StoreLayout.PAIRS) else []
    out = []
    for r in index:
        if r["id"] == sid and r["status"] == "done":
            src, dst = read_pair(store, sid, r["group"])
            out.append({"group": r["group"], "part": r["part"], "src": src, "dst": dst})
    return out


class StoredPairMapper:
    """The cage tracker's mapper for sample ``sid``: a part's vertices go where its stored pair sent
    them (:func:`proctex.store.samples.read_pair_vertices`: the same solve, with the same seed and
    settings) when that map was made for this very part; otherwise ``solver`` solves the pair."""

    def __init__(self, store: FamilyStore, sid: str, solver: Any) -> None:
        self.store, self.sid, self.solver = store, sid, solver

    def map(self, group: int, vertices: np.ndarray, faces: np.ndarray, query: np.ndarray, seed: int = 0) -> np.ndarray:
        mapped = read_pair_vertices(self.store, self.sid, group, vertices, faces) if self.sid and query is vertices else None
        return mapped if mapped is not None else self.solver.map(group, vertices, faces, query, seed=seed)


class _Context:
    """What evaluating a shape needs, loaded once per process: assets, the tracker and its template
    colours, the truth, the template's reference views, mappers by name, settings."""

    def __init__(self, uri: str, settings: dict[str, Any]) -> None:
        self.store = FamilyStore(uri)
        self.config = stored_config(self.store)
        self.settings = settings
        self.look = resolve_look(self.store, settings.get("look"))  # the look whose textures are measured
        self.assets = load_assets(self.store, look=self.look)
        self.truth_kind = settings["truth"]
        # a folder family's truth lies beside its files (proctex.sources.truthfiles): read for measuring only
        self.file_truth = self.config.source.folder if self.truth_kind == "canonical" and self.config.source.folder else None
        self.template = self.assets.shape
        if self.file_truth:
            self.truth_files = sample_mesh_paths(self.file_truth)  # read once: the samples' mesh files
            self.template = self.with_truth(self.template, FamilyState.load(self.store).stage("template").get("id", ""))
        # the truth's own view of the template's parts (their labels, where a file's truth gave them): for
        # locating and scoring only; the methods keep the build's grouping, which never saw the truth
        self.truth_grouping = self.assets.grouping if not self.file_truth else labelled_grouping(self.assets.grouping, self.template)
        self.up = self.config.up_axis()
        self.tracker = self.truth_kind or "cage"
        self.points = tracked_points(self.template, self.truth_grouping, self.tracker, n=settings["tracked"], seed=settings["seed"])
        self.truth = template_truth(self.template, self.truth_grouping, self.assets, self.truth_kind) if self.truth_kind else None
        uv = self.store.read_arrays(StoreLayout.UV)
        self.template_colours = colours_at(Location(self.points.face, self.points.bary), uv["corner_uv"], uv["face_group"], self.assets.textures)
        if not np.isfinite(self.template_colours).all():
            raise ValueError(f"{uri}: the template itself is untextured at some tracked points (template/uv.npz)")
        self.lpips = None
        if settings.get("lpips"):
            self.lpips = LPIPS.load(settings["lpips"])
        # The template's own six views: what every transferred shape is compared with (docs/results.md).
        tpl = transfer(self.template, self.assets, IdentityMapper(), seed=settings["seed"])
        self.reference, _ = render_six_views(self.template.vertices, self.template.faces, tpl.corner_uv, tpl.face_group, self.assets.textures, self.up, settings["view_size"])
        self.mappers: dict[str, Any] = {}
        # Parts of a kind the template lacks are painted as the service paints them (the family's
        # prompt, read on the new shape), so coverage measures the run-time path, not a gap of
        # the evaluation.

        self.painter = SurfacePainter(look_paint(self.store, self.look, self.config.paint).prompt, seed=self.config.seed)
        self.pairs_index = self.store.read_table(StoreLayout.PAIRS).to_pylist() if self.store.exists(StoreLayout.PAIRS) else []

    def with_truth(self, shape, sample_id: str):
        """``shape`` (folder sample ``sample_id``) with its file's truth where the family reads it there."""
        if not self.file_truth:
            return shape

        if sample_id not in self.truth_files:
            raise ValueError(f"{self.file_truth}: no sample {sample_id!r} (the folder changed since the build)")
        return attach_file_truth(shape, self.truth_files[sample_id])

    def mapper(self, name: str) -> Any:
        if name not in self.mappers:
            self.mappers[name] = _mapper(name, self.store, self.assets, self.config)
        return self.mappers[name]

    def locate(self, shape, seg, index: int, sid: str = ""):
        """Where the tracked points lie on ``shape`` (sample ``index``, id ``sid``), by the family's tracker."""
        if self.tracker == "canonical":
            return locate_canonical(self.points, self.template, self.truth_grouping.segmentation, shape, seg)
        if self.tracker == "vertex-index":
            return locate_vertex_index(self.points, shape, seg)
        # The cage, solved once per (shape, group) with the build's pair seeds, for every method:
        # the pairs stage kept where it sends a test part's vertices, so only a pair without that
        # map (a train shape, an older store, another part) is solved here.
        cage = SolverMapper(self.assets, "cage", n_points=self.config.corr_points, cage=_cage_config(self.config))
        seeds = {g.group: pair_seed(self.config, index, g.group) for g in self.assets.groups}
        return locate_by_map(self.points, self.template, shape, seg, assign_parts(shape, seg, self.assets), self.assets, StoredPairMapper(self.store, sid, cage), seeds)


def evaluate_method(
    ctx: _Context, name: str, shape, seg, loc, samples, pairs: list[dict[str, Any]], sid: str = "", views: list | None = None, atlases: dict | None = None, plain=None
) -> dict[str, Any]:
    """One shape with one method: transfer (timed, GLB included), bake, coverage of both, colours at
    the tracked points (real-time and baked), ground-truth and pseudo-ground-truth errors, view
    similarity with the template. A transfer that raises counts as a failed shape. ``views``: the
    shape's six canonical views traced already (:func:`proctex.texture.render.canonical_buffers`
    at the view size), ``atlases``: its bake atlases so far (:func:`proctex.transfer.apply.bake`),
    both shared by the methods of one shape (the same figures as tracing and unwrapping again).
    ``plain``: the shape as the method sees it where ``shape`` carries a truth it must not (a folder
    family's file truth: labels and canonical coordinates); the same vertices and faces."""
    st, assets, up = ctx.settings, ctx.assets, ctx.up
    t = time.perf_counter()
    mapper = ctx.mapper(name)
    try:
        result = shape_to_glb(shape if plain is None else plain, assets, mapper, seed=st["seed"], up=up, shortcut=name in shortcut_methods(), painter=ctx.painter).result
    except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
        # A failed shape counts: every located point untextured, every point with a truth failed.
        failed = np.where((loc.face >= 0)[:, None], np.inf, np.nan).repeat(3, axis=1).astype(np.float32)
        nothing = SimpleNamespace(assignment=[], points={})
        gt = gt_errors(shape, seg, samples, nothing, assets, ctx.truth)[0].astype(np.float32) if samples is not None else None
        pgt, pgt_groups, pgt_pairs = pgt_errors(shape, seg, nothing, assets, pairs)
        return {
            "colours": failed,
            "colours_baked": failed,
            "gt": gt,
            "gt_groups": None,
            "pgt": pgt.astype(np.float32),
            "pgt_groups": pgt_groups.astype(np.int32),
            "pgt_pairs": pgt_pairs,
            "sim": None,
            "record": {"id": sid, "failed": f"{type(exc).__name__}: {exc}", "seconds": time.perf_counter() - t, "coverage": 1.0, "coverage_baked": 1.0, "parts": 0, "mapped_parts": 0, "notes": []},
        }
    seconds = time.perf_counter() - t
    baked = bake(shape, result, assets, size=st["bake_size"], pbr=False, atlases=atlases)  # colours are measured, not PBR maps
    textures = list(assets.textures) + list(result.new_textures)
    masks = list(assets.painted) + [np.ones(x.shape[:2], bool) for x in result.new_textures]
    if views is None:
        views = canonical_buffers(shape.vertices, shape.faces, up, st["view_size"])
    c1 = coverage(shape.vertices, shape.faces, result.corner_uv, result.face_group, masks, up=up, size=st["view_size"], views=views).share
    c2 = coverage(shape.vertices, shape.faces, baked.corner_uv, baked.face_group, baked.painted, up=up, size=st["view_size"], views=views).share
    images, _ = render_six_views(shape.vertices, shape.faces, result.corner_uv, result.face_group, textures, up, st["view_size"], views=views)
    sim = view_similarity(ctx.reference, images, ctx.lpips)
    out: dict[str, Any] = {
        "colours": colours_at(loc, result.corner_uv, result.face_group, textures).astype(np.float32),
        "colours_baked": colours_at(loc, baked.corner_uv, baked.face_group, baked.textures).astype(np.float32),
        "gt": None,
        "gt_groups": None,
        "sim": sim,
    }
    if samples is not None:
        e, g, fl = gt_errors(shape, seg, samples, result, assets, ctx.truth, flips=True)
        out["gt"], out["gt_groups"], out["gt_flipped"] = e.astype(np.float32), g.astype(np.int32), fl.astype(np.float32)
    e, g, means, fl = pgt_errors(shape, seg, result, assets, pairs, flips=True)
    out["pgt"], out["pgt_groups"], out["pgt_pairs"], out["pgt_flipped"] = e.astype(np.float32), g.astype(np.int32), means, fl.astype(np.float32)
    active = [a for a in result.assignment if a.how != "degenerate"]
    mapped = [a for a in active if a.group >= 0 and a.part not in result.direct]
    serves = getattr(mapper, "serves", None)  # what the build chose per group (network mappers only)
    out["record"] = {
        "id": sid,
        "seconds": seconds,
        "bake_seconds": baked.seconds,
        "coverage": c1,
        "coverage_baked": c2,
        "ssim": sim.ssim,
        "psnr": sim.psnr,
        "lpips": sim.lpips,
        "parts": len(active),
        "mapped_parts": len(mapped),
        # Of those, the parts a network mapped (not the box map or identity the build chose instead).
        "network_parts": len([a for a in mapped if serves(a.group) == "network"]) if serves else 0,
        "new_parts": len([a for a in active if a.how == "new"]),
        "gt_mean": float(np.nanmean(out["gt"])) if out["gt"] is not None and (~np.isnan(out["gt"])).any() else None,
        "pgt_mean": float(e.mean()) if len(e) else None,
        "notes": list(result.notes),
    }
    return out


def evaluate_shape(ctx: _Context, job: tuple[int, dict[str, Any]]) -> dict[str, Any]:
    """Every method of ``ctx.settings["methods"]`` on one shape (``job``: its sample index and
    row); the tracker's locations, the truth samples and the stored pairs are found once."""
    index, row = job
    plain = load_sample(ctx.store, row, ctx.config)
    shape = ctx.with_truth(plain, row["id"])  # for locating and scoring; the methods get the plain shape
    seg = segment(shape)
    loc = ctx.locate(shape, seg, index, row["id"])
    samples = truth_samples(shape, seg, ctx.truth_kind, n=ctx.settings["tracked"], seed=ctx.settings["seed"] + index) if ctx.truth_kind else None
    pairs = stored_pairs(ctx.store, row["id"], ctx.pairs_index)
    # the shape's views traced and its bake atlases unwrapped once for all methods (the evaluation
    # of the sofa export's 50 test shapes on 2 workers: 68.1 -> 46.6 s, the same metrics)
    views = canonical_buffers(shape.vertices, shape.faces, ctx.up, ctx.settings["view_size"])
    atlases: dict = {}
    return {m: evaluate_method(ctx, m, shape, seg, loc, samples, pairs, row["id"], views, atlases, plain if ctx.file_truth else None) for m in ctx.settings["methods"]}


_WORKER: dict[str, Any] = {}


def _work(task: tuple[str, dict[str, Any], tuple[int, dict[str, Any]]]) -> dict[str, Any]:
    """One shape in a worker process; the evaluation's context is built once a process and
    evaluation (``uri`` and ``settings``) and kept for its next shapes."""
    import json

    uri, settings, job = task
    key = json.dumps([uri, settings], sort_keys=True, default=str)
    if _WORKER.get("key") != key:
        _WORKER.clear()
        _WORKER.update(key=key, ctx=_Context(uri, settings))
    return evaluate_shape(_WORKER["ctx"], job)


def _per_group(errors: np.ndarray, groups: np.ndarray) -> dict[str, dict[str, float]]:
    return {str(int(g)): {"mean": float(errors[groups == g].mean()), "max": float(errors[groups == g].max())} for g in np.unique(groups) if g >= 0}


def summarise_method(ctx_points, tracker: str, template_colours: np.ndarray, outs: list[dict[str, Any]]) -> dict[str, Any]:
    """One method's entry of ``metrics.json`` from its per-shape outputs (:func:`evaluate_method`)."""
    per_shape = [o["record"] for o in outs]
    ok = [o for o in outs if o["sim"] is not None]
    tv = tracked_variance(template_colours, [o["colours"] for o in outs], ctx_points.group, tracker)
    tvb = tracked_variance(template_colours, [o["colours_baked"] for o in outs], ctx_points.group, tracker)
    secs = [r["seconds"] for r in per_shape if "failed" not in r]
    cov = [r["coverage"] for r in per_shape]
    parts = sum(r["parts"] for r in per_shape)
    entry: dict[str, Any] = {
        "tracker": tracker,
        # Colours from each shape's own baked texture (docs/results.md); also through the real-time UVs.
        "tracked_point_variance": tvb.value,
        "tracked_point_variance_realtime": tv.value,
        "tracked_point_variance_per_group": tvb.to_dict()["per_group"],
        "tracked_points": tv.points,
        "tracked_missing": tv.missing,
        "gt_error": None,
        "pgt_error": None,
        "coverage": float(max(cov)),
        "coverage_mean": float(np.mean(cov)),
        "coverage_baked": float(max(r["coverage_baked"] for r in per_shape)),
        "shapes_with_holes": int(sum(c > 0 for c in cov)),
        "failed_shapes": int(len(outs) - len(ok)),
        # Renders of the template vs of each transferred shape, six canonical views.
        "ssim": float(np.mean([o["sim"].ssim for o in ok])) if ok else None,
        "psnr": float(np.mean([o["sim"].psnr for o in ok])) if ok else None,
        "lpips": float(np.mean([o["sim"].lpips for o in ok])) if ok and ok[0]["sim"].lpips is not None else None,
        "seconds_per_shape": float(np.median(secs)) if secs else None,
        "seconds": _summary(secs),
        "bake_seconds": _summary([r["bake_seconds"] for r in per_shape if "bake_seconds" in r]),
        "parts": int(parts),
        "mapped_parts": int(sum(r["mapped_parts"] for r in per_shape)),
        "mapped_share": float(sum(r["mapped_parts"] for r in per_shape) / parts) if parts else 0.0,
        "network_share": float(sum(r.get("network_parts", 0) for r in per_shape) / parts) if parts else 0.0,
        # Parts of a kind the template lacks (painted as new groups at run time, untextured here).
        "new_parts": int(sum(r.get("new_parts", 0) for r in per_shape)),
        "new_share": float(sum(r.get("new_parts", 0) for r in per_shape) / parts) if parts else 0.0,
        "per_shape": per_shape,
    }
    gts = [o["gt"] for o in outs if o["gt"] is not None]
    if gts:
        e = np.concatenate(gts)
        worst = [float(np.nanmean(x)) for x in gts if (~np.isnan(x)).any()]
        entry["gt_error"] = (
            {
                **error_summary(e),
                "worst_shape_mean": max(worst),
                # the share of the measured points that have a truth (a .blend point whose
                # node the template lacks has none)
                "with_truth": float(np.mean(~np.isnan(e))) if len(e) else 0.0,
            }
            if worst
            else None
        )
        groups = [o["gt_groups"] for o in outs if o["gt_groups"] is not None]
        if groups and entry["gt_error"]:
            entry["gt_error"]["per_group"] = _per_group(np.concatenate([o["gt"] for o in outs if o["gt_groups"] is not None]), np.concatenate(groups))
        flips = [o["gt_flipped"] for o in outs if o.get("gt_flipped") is not None]
        if flips and entry["gt_error"]:
            # Share of measured points landing on a template face that faces away from the true one
            # (the other side of a thin wall), overall and per group.
            fl, fg = np.concatenate(flips), np.concatenate([o["gt_groups"] for o in outs if o.get("gt_flipped") is not None])
            ok = ~np.isnan(fl)
            entry["gt_error"]["flipped"] = float(fl[ok].mean()) if ok.any() else None
            for key, pg in entry["gt_error"].get("per_group", {}).items():
                sel = ok & (fg == int(key))
                pg["flipped"] = float(fl[sel].mean()) if sel.any() else None
    pg = [o["pgt"] for o in outs if len(o["pgt"])]
    if pg:
        means = [m for o in outs for m in o["pgt_pairs"]]
        entry["pgt_error"] = {**error_summary(np.concatenate(pg)), "worst_pair_mean": float(max(means)), "pairs": len(means)}
        groups = [o["pgt_groups"] for o in outs if o["pgt_groups"] is not None and len(o["pgt"])]
        if groups:
            entry["pgt_error"]["per_group"] = _per_group(np.concatenate([o["pgt"] for o in outs if o["pgt_groups"] is not None and len(o["pgt"])]), np.concatenate(groups))
        flips = [o["pgt_flipped"] for o in outs if o.get("pgt_flipped") is not None and len(o["pgt_flipped"])]
        if flips:
            # Against the cage teacher, where no truth exists: points landing on a template face
            # that faces away from the one their cage point lies on.
            fl = np.concatenate(flips)
            entry["pgt_error"]["flipped"] = float(np.nanmean(fl)) if (~np.isnan(fl)).any() else None
    return entry


def evaluate(
    store: FamilyStore,
    methods: Sequence[str] | None = None,
    split: str = "test",
    limit: int | None = None,
    bake_size: int = 512,
    view_size: int = 256,
    tracked: int = 5000,
    seed: int = 0,
    lpips: str | None = None,
    workers: int = 1,
    truth: str = "auto",
    log: Callable[[str], None] = print,
    quiet: bool = False,
    look: str | None = None,
) -> dict[str, Any]:
    """Evaluate the family in ``store`` (module docstring), textured as its ``look`` (default: the
    build's; the colour metrics, the tracked-point variance among them, are per look); returns the
    metrics dict (not written).

    Args:
        methods: the methods to compare (:mod:`proctex.transfer.methods`; None: :func:`default_methods`).
        split: which samples ("test": the unseen shapes; "train").
        limit: evaluate at most this many shapes (the first ones).
        bake_size: baked texture size; view_size: coverage and view-similarity render size;
        tracked: tracked points (and truth samples per shape; vertex-index truth uses every vertex);
        lpips: a local LPIPS weights file (:mod:`proctex.texture.lpips`), optional.
        workers: processes evaluating shapes in parallel (1: this process).
        truth: the ground truth (:func:`resolve_truth`); "auto": the family config's.
        quiet: no progress lines.
    """
    methods = default_methods() if methods is None else tuple(methods)
    known = method_names(aliases=True)
    unknown = [m for m in methods if m not in known]
    if unknown or not methods:
        raise ValueError(f"methods must be a non-empty subset of {', '.join(known)}, got {list(methods)}")
    if split not in ("train", "test"):
        raise ValueError(f"split must be train or test, got {split!r}")
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    if tracked < 10:
        raise ValueError(f"tracked must be >= 10, got {tracked}")
    config = stored_config(store)
    kind = resolve_truth(config, truth)
    all_rows = samples(store)
    jobs = [(i, r) for i, r in enumerate(all_rows) if r["split"] == split][: limit if limit is not None else None]
    if len(jobs) < 1:
        raise ValueError(f"{store.uri}: evaluation needs at least one {split} shape besides the template, found none")
    if kind == "vertex-index":  # a clear error before any work: every sample must share the template's vertex order
        n = load_template_shape(store, config).n_vertices
        bad = next((r for _, r in jobs if r["vertices"] != n), None)  # the sample stage records vertex counts
        if bad is not None:
            check_vertex_index(load_sample(store, bad, config), n, name=f"sample {bad['id']}")
    if lpips:
        LPIPS.load(lpips)  # a bad weights file fails before any work
    settings = {"bake_size": bake_size, "view_size": view_size, "tracked": tracked, "seed": seed, "lpips": lpips, "truth": kind, "methods": list(methods), "look": resolve_look(store, look).name}
    ctx = _Context(store.uri, settings)
    log(f"evaluate: {len(jobs)} {split} shapes, {', '.join(methods)}; tracker {ctx.tracker} ({len(ctx.points)} points)" + (f", ground truth {kind}" if kind else ", no ground truth"))
    t0 = time.perf_counter()
    bar = Progress("evaluate", len(jobs), quiet=quiet)
    outs: list[dict[str, Any]] = []
    if workers > 1 and len(jobs) > 1:
        # the build's worker processes where it shares them (each keeps its context: _work)
        with process_pool(min(workers, len(jobs))) as pool:
            for out in pool.map(_work, [(store.uri, settings, job) for job in jobs]):
                outs.append(out)
                bar.update()
    else:
        for job in jobs:
            outs.append(evaluate_shape(ctx, job))
            bar.update()
    metrics: dict[str, Any] = {
        "split": split,
        "look": ctx.look.name,
        "shapes": len(jobs),
        "ids": [r["id"] for _, r in jobs],
        "tracker": ctx.tracker,
        "truth": kind,
        "tracked_points": len(ctx.points),
        "lpips_weights": lpips,
        "shortcut": sorted(shortcut_methods()),
        "seconds": round(time.perf_counter() - t0, 2),
        "methods": {},
    }
    for name in methods:
        entry = summarise_method(ctx.points, ctx.tracker, ctx.template_colours, [o[name] for o in outs])
        metrics["methods"][name] = entry
        gt, pgt = entry["gt_error"] or {}, entry["pgt_error"] or {}
        log(
            f"evaluate {name}: tracked variance {entry['tracked_point_variance']:.4f} baked, {entry['tracked_point_variance_realtime']:.4f} "
            f"real-time ({ctx.tracker}); "
            + (f"GT error mean {gt['mean']:.4f} max {gt['max']:.4f}; " if gt else "")
            + (f"pseudo-GT mean {pgt['mean']:.4f} max {pgt['max']:.4f}; " if pgt else "")
            + f"coverage max {entry['coverage']:.4f} (baked {entry['coverage_baked']:.4f}); mapped {entry['mapped_share']:.0%} of parts, "
            + f"by a network {entry['network_share']:.0%}; "
            + f"new parts (a kind the template lacks) {entry['new_share']:.0%}; "
            + (f"{1000 * entry['seconds_per_shape']:.0f} ms per shape" if entry["seconds_per_shape"] is not None else "every shape failed")
        )
    return metrics


def markdown_table(metrics: dict[str, Any]) -> str:
    """A Markdown table of :func:`evaluate`'s metrics, one row per method."""

    def f(x: Any, nd: int = 4) -> str:
        return "-" if x is None else f"{x:.{nd}f}"

    has_lpips = any(m.get("lpips") is not None for m in metrics["methods"].values())
    truth = metrics.get("truth") or "none"
    lines = [
        f"{metrics['shapes']} {metrics['split']} shapes; tracked points: {metrics.get('tracker')} ({metrics.get('tracked_points')}); "
        f"ground truth: {truth}; errors in the template part's normalised frame, max = over all points; "
        f"parts of a kind the template lacks: {next(iter(metrics['methods'].values()), {}).get('new_share', 0.0):.0%}",
        "",
        "| method | tracked-point variance (baked / real-time) | GT error mean / p95 / max | pseudo-GT error mean / max "
        "| coverage (real-time / baked) | parts by a network, of parts mapped | SSIM | PSNR (dB) |" + (" LPIPS |" if has_lpips else "") + " ms per shape |",
        "|---|---|---|---|---|---|---|---|" + ("---|" if has_lpips else "") + "---|",
    ]
    for name, m in metrics["methods"].items():
        pgt = m.get("pgt_error") or {}
        gt = m.get("gt_error") or {}
        ms = "-" if m.get("seconds_per_shape") is None else f"{1000 * m['seconds_per_shape']:.0f}"
        nets = f"{m.get('network_share', m['mapped_share']):.0%} of {m['mapped_share']:.0%}" if name.startswith("corrnet") else "-"
        lines.append(
            f"| {name} | {f(m['tracked_point_variance'])} / {f(m['tracked_point_variance_realtime'])} | "
            f"{f(gt.get('mean'))} / {f(gt.get('p95'))} / {f(gt.get('max'))} | {f(pgt.get('mean'))} / {f(pgt.get('max'))} | "
            f"{f(m['coverage'])} / {f(m['coverage_baked'])} | {nets} | {f(m.get('ssim'), 3)} | {f(m.get('psnr'), 1)} |" + (f" {f(m.get('lpips'), 3)} |" if has_lpips else "") + f" {ms} |"
        )
    return "\n".join(lines)
