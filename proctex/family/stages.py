"""A family as a unit: build it stage by stage into a store, load it back for transfer (DESIGN §3).

Stages, each idempotent (a rerun skips what is complete and redoes what is missing or failed):

1. ``sample``   — sample the procedural model (or read a folder of samples): ``samples.parquet``, ``meshes/``.
2. ``template`` — the sample nearest the mean parameters: ``template/template.obj``.
3. ``paint``    — parts, groups, UVs and one texture per group: ``template/``.
4. ``pairs``    — the cage correspondence of every (train or test shape, template group):
   ``correspondences/<id>__g<group>.parquet`` and ``pairs.parquet``.
5. ``train``    — one ProcCorrNet per group: ``models/group_<g>.pt``.
6. ``evaluate`` — transfer to the test shapes and measure (:mod:`proctex.family.evaluate`): ``metrics.json``.

Each stage is a :class:`proctex.family.plan.Plan` (``plan_sample``, ``plan_pairs``, ``plan_train``; the
one-step stages run in place): ``stage_<name>`` runs it in this process, the Ray build
(``workflows/build.py``) fans the same plans out over a cluster.
"""

from __future__ import annotations

import json
import os
import platform
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pyarrow as pa

from proctex.geometry.meshio import load_mesh_bytes, obj_text
from proctex.geometry.parts import analyse, part_mesh, segment
from proctex.geometry.shape import Shape
from .config import BuildConfig, resolved_settings, with_legacy, without_devices
from .plan import Plan, run_in_process
from .store import MAP_KINDS, FamilyStore, StoreLayout, check_digest, digest

STAGES = ("sample", "template", "paint", "pairs", "train", "evaluate")


# --------------------------------------------------------------------------------------- helpers
def _versions() -> dict[str, str]:
    import numpy
    import scipy
    import torch
    import trimesh

    return {"python": platform.python_version(), "numpy": numpy.__version__, "scipy": scipy.__version__, "torch": torch.__version__, "trimesh": trimesh.__version__, "pyarrow": pa.__version__}


def _state(store: FamilyStore) -> dict[str, Any]:
    return store.read_json(StoreLayout.STATE) if store.exists(StoreLayout.STATE) else {}


def _mark(store: FamilyStore, stage: str, **info: Any) -> None:
    state = _state(store)
    state.setdefault("stages", {})[stage] = {"state": "done", "finished": time.strftime("%Y-%m-%dT%H:%M:%S"), **info}
    store.write_json(StoreLayout.STATE, state)


def stage_done(store: FamilyStore, stage: str) -> bool:
    return _state(store).get("stages", {}).get(stage, {}).get("state") == "done"


# ----------------------------------------------------------------------------------------- stages
@dataclass
class SampleJob:
    """One sample of the family: its position in the sample list, id, split and parameters."""

    index: int
    id: str
    split: str
    params: dict[str, Any]


def sample_jobs(config: BuildConfig) -> list[SampleJob]:
    """Every sample of the family (the folder's, or ``n_train + n_test`` drawn from the model with the
    family seed), in order."""
    if config.source.folder:
        src = _folder(config.source.folder)
        return [SampleJob(i, s.id.replace("/", "_"), s.split, src.params(i)) for i, s in enumerate(src.samples)]
    model = config.procedural_model()
    params = model.space.sample(config.source.n_train + config.source.n_test, seed=config.seed, method=config.source.sampling)
    return [SampleJob(i, f"s{i:04d}", "train" if i < config.source.n_train else "test", p) for i, p in enumerate(params)]


_FOLDERS: dict[str, Any] = {}


def _folder(path: str):
    from .sources import FolderSource

    if path not in _FOLDERS:
        _FOLDERS[path] = FolderSource(path)
    return _FOLDERS[path]


def run_sample_job(store: FamilyStore, config: BuildConfig, job: SampleJob) -> dict[str, Any]:
    """Make one sample, write its mesh and its record (the mesh first: a record means both are
    complete); returns the record, a row of ``samples.parquet``. Idempotent."""
    rel = StoreLayout.sample_record(job.id)
    if store.exists(rel):
        return store.read_json(rel)
    shape = _folder(config.source.folder).load(job.index) if config.source.folder else config.procedural_model().generate(job.params)
    path = StoreLayout.mesh(job.id)
    store.write_bytes(path, obj_text(shape.vertices, shape.faces).encode())
    seg = segment(shape)
    row = {"id": job.id, "split": job.split, "params": json.dumps(job.params, sort_keys=True), "mesh": path,
           "vertices": shape.n_vertices, "faces": shape.n_faces, "parts": seg.n_parts}
    store.write_json(rel, row)
    return row


def finish_sample_stage(store: FamilyStore, rows: list[dict[str, Any]]) -> None:
    """Write ``samples.parquet`` (rows in sample order) and mark the stage done."""
    store.write_table(StoreLayout.SAMPLES, pa.Table.from_pylist(rows))
    _mark(store, "sample", samples=len(rows), train=sum(r["split"] == "train" for r in rows))


SAMPLE_BATCH = 8  # samples per batch (a Ray task)


def run_sample_batch(store: FamilyStore, config: BuildConfig, jobs: list[SampleJob], context: Any = None) -> list[dict[str, Any]]:
    """Make and store a batch of samples; their ``samples.parquet`` rows."""
    return [run_sample_job(store, config, job) for job in jobs]


def plan_sample(store: FamilyStore, config: BuildConfig, log: Callable[[str], None] = print) -> Plan:
    """The sample stage: every sample (the folder's, or drawn from the model) into ``meshes/`` and
    ``samples.parquet``, in batches of :data:`SAMPLE_BATCH`."""
    if stage_done(store, "sample"):
        return Plan("sample", [], run_sample_batch, finish=lambda results: None, skip="done already")
    jobs = sample_jobs(config)

    def finish(results: list[list[dict[str, Any]]]) -> None:
        rows = [row for out in results for row in out]
        finish_sample_stage(store, rows)
        log(f"sample: {len(rows)} shapes")

    return Plan("sample", [jobs[i : i + SAMPLE_BATCH] for i in range(0, len(jobs), SAMPLE_BATCH)], run_sample_batch, finish)


def stage_sample(store: FamilyStore, config: BuildConfig, log: Callable[[str], None] = print) -> None:
    """Sample shapes (or read the folder) into ``meshes/`` and ``samples.parquet`` (:func:`plan_sample`, here)."""
    run_in_process(plan_sample(store, config, log), store, config, log)


def samples(store: FamilyStore) -> list[dict[str, Any]]:
    return store.read_table(StoreLayout.SAMPLES).to_pylist()


def _read_obj(store: FamilyStore, rel: str) -> Shape:
    shape, _ = load_mesh_bytes(store.read_bytes(rel), rel)
    return shape


def load_sample(store: FamilyStore, row: dict[str, Any], config: BuildConfig | None = None) -> Shape:
    """A sample as a :class:`Shape`. Model families regenerate it from its parameters (exact, with
    labels and canonical coordinates); folder families read the stored mesh."""
    params = json.loads(row["params"])
    if config is not None and not config.source.folder:
        shape = config.procedural_model().generate(params)
        shape.source = row["mesh"]
        return shape
    shape = _read_obj(store, row["mesh"])
    shape.params = params
    return shape


def stage_template(store: FamilyStore, config: BuildConfig, log: Callable[[str], None] = print) -> None:
    """Pick the template among the train samples: of those with the most kinds of part
    (:func:`proctex.geometry.parts.part_kinds`, so a family with optional parts gets a template
    that carries them), the one nearest the mean parameters."""
    if stage_done(store, "template"):
        log("template: done already")
        return
    from proctex.geometry.parts import part_kinds
    from proctex.params import infer_space, select_template

    rows = [r for r in samples(store) if r["split"] == "train"]
    params = [json.loads(r["params"]) for r in rows]
    space = infer_space(params) if config.source.folder else config.procedural_model().space
    kinds = [part_kinds(_read_obj(store, r["mesh"])) for r in rows]
    i = select_template(space, params, coverage=kinds) if len(space) else int(np.argmax(kinds))
    nearest = select_template(space, params) if len(space) else 0
    store.write_bytes(StoreLayout.TEMPLATE_MESH, store.read_bytes(rows[i]["mesh"]))
    _mark(store, "template", id=rows[i]["id"], params=params[i], part_kinds=kinds[i])
    why = "" if i == nearest else f"; the sample nearest the mean ({rows[nearest]['id']}) has {kinds[nearest]}"
    log(f"template: {rows[i]['id']} ({kinds[i]} kinds of part, the most of the {len(rows)} train samples{why})")


def stage_paint(store: FamilyStore, config: BuildConfig, log: Callable[[str], None] = print) -> None:
    """Parts, groups, UVs and textures of the template into ``template/``."""
    if stage_done(store, "paint"):
        log("paint: done already")
        return
    import tempfile

    from proctex.texture.paint_loop import paint_template
    from .template import write_textured

    template = load_template_shape(store, config)
    grouping = analyse(template, seed=config.seed)
    uv = None
    if config.source.blender and config.source.blender.get("uv"):  # the graph's own UVs, as the user asked
        from proctex.texture.uv import source_uv

        if template.corner_uv is None:
            raise ValueError(f"the template has no UV map {config.source.blender['uv']!r}")
        uv = source_uv(template, grouping, template.corner_uv, resolution=config.paint.texture_size)
        for note in (n for a in uv.atlases for n in a.notes):
            log(f"paint: {note}")
    tex = paint_template(template, grouping, config.paint.prompt, config.paint.group_prompts, painter=config.paint.painter, size=config.paint.texture_size,
                         seed=config.seed, up=config.up_axis(), views=config.paint.views, view_size=config.paint.view_size,
                         complete_hidden=config.paint.paint_hidden, fill=config.paint.fill, model_dir=config.paint.model_dir, device=config.paint.device,
                         steps=config.paint.steps, on_view=lambda k, n, st: log(f"paint: view {k + 1}/{n}, {st['texels_updated']} texels"), uv=uv,
                         occlusion=config.paint.occlusion)
    from .template import Template

    labels = [g.label for g in tex.groups]
    record = Template(template, grouping, tex.uv.corner_uv, tex.uv.face_group, [g.uint8() for g in tex.groups], labels,
                      tex.painted_masks, tex.observed_masks, tex.pbr if any(m is not None for m in tex.pbr) else None)
    with tempfile.TemporaryDirectory() as tmp:
        summary = write_textured(tex, tmp, up=config.up_axis())
        textures = {StoreLayout.texture(g, label, kind) for g, label in enumerate(labels) for kind in ("", *MAP_KINDS)}  # the record writes those
        for name in sorted(os.listdir(tmp)):
            if StoreLayout.template_file(name) not in textures:
                store.write_bytes(StoreLayout.template_file(name), (Path(tmp) / name).read_bytes())
    record.save(store)
    _mark(store, "paint", coverage=summary["coverage"]["share"], groups=len(grouping.groups), seconds=round(tex.seconds, 3))
    log(f"paint: {len(grouping.groups)} groups, unpainted visible pixels {100 * summary['coverage']['share']:.3f}%")


def load_template_shape(store: FamilyStore, config: BuildConfig | None = None) -> Shape:
    """The template shape (regenerated from its parameters for model families, see :func:`load_sample`)."""
    config = config if config is not None else stored_config(store)
    if not config.source.folder:
        params = _state(store)["stages"]["template"]["params"]
        shape = config.procedural_model().generate(params)
        shape.source = StoreLayout.TEMPLATE_MESH
        return shape
    return _read_obj(store, StoreLayout.TEMPLATE_MESH)


def stored_config(store: FamilyStore) -> BuildConfig:
    """The config the family was built with. Its devices read as "cpu": where a family was built
    (a GPU, say) is not where it is used; readers choose their own device."""
    state = _state(store)
    if "config" not in state:
        raise ValueError(f"{store.uri}: not a ProcTex family (no family.json with a config)")
    return BuildConfig.from_dict(without_devices(with_legacy(state["config"])))


def load_template(store: FamilyStore, config: BuildConfig | None = None):
    """The stored :class:`proctex.family.template.Template` (its mesh regenerated for model families)."""
    from .template import Template

    config = config if config is not None else stored_config(store)
    return Template.load(store, load_template_shape(store, config), seed=config.seed)


def load_assets(store: FamilyStore):
    """The template ready for transfer (:class:`proctex.family.assets.TemplateAssets`), from the store."""
    return load_template(store).assets()


def solve_pair(shape: Shape, assets, group: int, config: BuildConfig, seed: int) -> dict[str, Any] | None:
    """Cage correspondence of one (shape, template group): the training pair and its record."""
    from proctex.correspond.dense import correspond_parts
    from .assign import assign_parts, choose_part, representative_part

    seg = segment(shape)
    a = choose_part(assign_parts(shape, seg, assets), group)
    if a is None:
        return None
    vn, f = representative_part(*part_mesh(shape, seg.parts[a.part]), a)  # winding kept outward under a mirror
    ga = assets.groups[group]
    cage = config.cage
    res = correspond_parts(vn, f, ga.vertices, ga.faces, method="cage", n_points=config.corr_points, seed=seed, cage=cage)
    return {
        "part": a.part,
        "src": res.source_points.astype(np.float32),
        "dst": res.points.astype(np.float32),  # template normalised frame (the representative is stored normalised)
        "face": res.faces.astype(np.int32),
        "residual": res.residual,
        "chamfer": res.chamfer,
        "converged": res.converged,
        "iterations": res.iterations,
        "seconds": res.seconds,
    }


@dataclass
class PairJob:
    """One cage correspondence to solve: sample ``index`` (its ``samples.parquet`` row) and template ``group``."""

    index: int
    row: dict[str, Any]
    group: int

    @property
    def key(self) -> tuple[str, int]:
        return (self.row["id"], self.group)


def pair_seed(config: BuildConfig, index: int, group: int) -> int:
    """The seed of pair (sample ``index``, ``group``): a function of the family seed and the pair only,
    so any process, in any order, solves a pair the same way."""
    return config.seed * 1_000_003 + index * 97 + group


def pair_jobs(store: FamilyStore, config: BuildConfig, assets=None, splits: tuple[str, ...] = ("train", "test")) -> list[PairJob]:
    """Every (shape of ``splits``, non-degenerate template group) pair, in sample order."""
    assets = assets if assets is not None else load_assets(store)
    groups = [g.group for g in assets.groups if not g.degenerate]
    return [PairJob(i, r, g) for i, r in enumerate(samples(store)) if r["split"] in splits for g in groups]


def pair_records(store: FamilyStore, jobs: list[PairJob]) -> dict[tuple[str, int], dict[str, Any]]:
    """The stored record of each job that has one (done, absent or failed). Stores written before
    per-pair records existed: the rows of ``pairs.parquet`` whose data file exists."""
    index = {}
    if store.exists(StoreLayout.PAIRS):
        index = {(r["id"], r["group"]): r for r in store.read_table(StoreLayout.PAIRS).to_pylist()}
    out = {}
    for job in jobs:
        rel = StoreLayout.pair_record(*job.key)
        if store.exists(rel):
            out[job.key] = store.read_json(rel)
        elif job.key in index and (index[job.key]["status"] == "absent" or (index[job.key]["status"] == "done" and store.exists(StoreLayout.pair(*job.key)))):
            out[job.key] = index[job.key]
    return out


def pair_complete(record: dict[str, Any] | None) -> bool:
    """A pair needs no more work: solved, or the shape lacks the group."""
    return record is not None and record.get("status") in ("done", "absent")


def run_pair_job(store: FamilyStore, config: BuildConfig, assets, job: PairJob, shape: Shape | None = None) -> dict[str, Any]:
    """Solve one pair and store it: the correspondence Parquet file first, then its JSON record, both
    atomic, so a record always describes complete data. A pair already complete is returned as is;
    a failure (``ValueError``/``RuntimeError``) is recorded as "failed" (retried by the next run).
    Returns the record (a row of ``pairs.parquet``)."""
    rel = StoreLayout.pair_record(*job.key)
    old = store.read_json(rel) if store.exists(rel) else None
    if pair_complete(old):
        return old
    sid, g = job.key
    t = time.perf_counter()
    try:
        shape = shape if shape is not None else load_sample(store, job.row, config)
        pair = solve_pair(shape, assets, g, config, pair_seed(config, job.index, g))
        status = "done" if pair is not None else "absent"
        error = ""
    except (ValueError, RuntimeError) as exc:
        pair, status, error = None, "failed", str(exc)
    if pair is not None:
        store.write_table(StoreLayout.pair(sid, g), {
            "sx": pair["src"][:, 0], "sy": pair["src"][:, 1], "sz": pair["src"][:, 2],
            "tx": pair["dst"][:, 0], "ty": pair["dst"][:, 1], "tz": pair["dst"][:, 2], "face": pair["face"],
        })
    record = {
        "id": sid, "split": job.row["split"], "group": g, "status": status, "error": error,
        "part": -1 if pair is None else int(pair["part"]),
        "residual": None if pair is None else float(pair["residual"]),
        "chamfer": None if pair is None else float(pair["chamfer"]),
        "converged": bool(pair and pair["converged"]), "iterations": 0 if pair is None else int(pair["iterations"]),
        "seconds": time.perf_counter() - t, "attempts": 1 + (old or {}).get("attempts", 0),
        "path": StoreLayout.pair(sid, g) if pair else "",
    }
    store.write_json(rel, record)
    return record


def write_pairs_index(store: FamilyStore, jobs: list[PairJob], records: dict[tuple[str, int], dict[str, Any]]) -> None:
    """``pairs.parquet``: one row per job that has a record, in job order (NaN for missing figures)."""
    rows = []
    for job in jobs:
        r = records.get(job.key)
        if r is not None:
            rows.append({**r, "residual": float("nan") if r["residual"] is None else r["residual"],
                         "chamfer": float("nan") if r["chamfer"] is None else r["chamfer"]})
    store.write_table(StoreLayout.PAIRS, pa.Table.from_pylist(rows))


def finish_pairs_stage(store: FamilyStore, jobs: list[PairJob], records: dict[tuple[str, int], dict[str, Any]], log: Callable[[str], None] = print) -> None:
    """Write the index; mark the stage done when every job is complete."""
    write_pairs_index(store, jobs, records)
    failed = sum(r["status"] == "failed" for r in records.values())
    missing = sum(job.key not in records for job in jobs)
    if failed or missing:
        log(f"pairs: {failed} failed, {missing} not run (rerun to retry)")
    else:
        _mark(store, "pairs", pairs=len(records))


INDEX_EVERY = 5.0  # seconds between rewrites of pairs.parquet while pairs arrive

# Template assets per (store, paint stamp), kept between batches by a process that runs pair batches
# without them (a Ray worker).
_ASSETS: dict[tuple[str, str], Any] = {}


def cached_assets(store: FamilyStore) -> Any:
    """The store's template assets, loaded once per process and paint stamp."""
    stamp = str(_state(store).get("stages", {}).get("paint", {}).get("finished", ""))
    key = (store.uri, stamp)
    if key not in _ASSETS:
        _ASSETS.clear()
        _ASSETS[key] = load_assets(store)
    return _ASSETS[key]


def run_pair_batch(store: FamilyStore, config: BuildConfig, jobs: list[PairJob], context: Any = None) -> list[dict[str, Any]]:
    """Solve and store a batch of cage pairs (one shape's: it is loaded once) with the template
    assets ``context`` (loaded here when None); their records."""
    assets = context if context is not None else cached_assets(store)
    records, shape, shape_id = [], None, None
    for job in jobs:
        if shape_id != job.row["id"]:
            shape, shape_id = None, job.row["id"]
            try:
                shape = load_sample(store, job.row, config)
            except (ValueError, RuntimeError):
                shape = None  # run_pair_job loads it again and records the failure
        records.append(run_pair_job(store, config, assets, job, shape))
    return records


def plan_pairs(store: FamilyStore, config: BuildConfig, log: Callable[[str], None] = print,
               splits: tuple[str, ...] = ("train", "test")) -> Plan:
    """The pairs stage: a cage pair for every (shape, non-degenerate template group) not complete
    yet, one batch per shape; ``pairs.parquet`` rewritten as they arrive. ``info["solved"]``: pairs run."""
    assets = load_assets(store)
    jobs = pair_jobs(store, config, assets, splits)
    records = pair_records(store, jobs)
    todo = [j for j in jobs if not pair_complete(records.get(j.key))]
    if not todo and stage_done(store, "pairs"):
        return Plan("pairs", [], run_pair_batch, finish=lambda results: None, skip="done already", info={"solved": 0})
    by_shape: dict[str, list[PairJob]] = {}
    for job in todo:
        by_shape.setdefault(job.row["id"], []).append(job)
    t0 = time.perf_counter()
    clock = {"solved": 0, "index": t0}

    def collect(batch: list[PairJob], out: list[dict[str, Any]]) -> None:
        for rec in out:
            records[(rec["id"], rec["group"])] = rec
        clock["solved"] += len(batch)
        now = time.perf_counter()
        if now - clock["index"] >= INDEX_EVERY:
            write_pairs_index(store, jobs, records)
            clock["index"] = now
        log(f"pairs: {batch[0].row['id']} ({clock['solved']}/{len(todo)} solved, {now - t0:.0f}s)")

    def finish(results: list[list[dict[str, Any]]]) -> None:
        finish_pairs_stage(store, jobs, records, log)
        plan.info.update(solved=len(todo), seconds=round(time.perf_counter() - t0, 2))

    plan = Plan("pairs", list(by_shape.values()), run_pair_batch, finish, collect, context=assets)
    return plan


def stage_pairs(store: FamilyStore, config: BuildConfig, log: Callable[[str], None] = print, splits: tuple[str, ...] = ("train", "test")) -> None:
    """Cage pairs for every (shape, non-degenerate template group); skips pairs already complete
    (:func:`plan_pairs`, here)."""
    run_in_process(plan_pairs(store, config, log, splits), store, config, log)


def read_pair(store: FamilyStore, sid: str, group: int, faces: bool = False):
    """(src (n, 3), dst (n, 3)) float32 of a stored pair; with ``faces``, also the (n,) template
    face of each target."""
    t = store.read_table(StoreLayout.pair(sid, group))
    src = np.stack([t.column(k).to_numpy() for k in ("sx", "sy", "sz")], axis=1)
    dst = np.stack([t.column(k).to_numpy() for k in ("tx", "ty", "tz")], axis=1)
    return (src, dst, t.column("face").to_numpy()) if faces else (src, dst)


def write_config(store: FamilyStore, config: BuildConfig) -> None:
    state = _state(store)
    old = state.get("config")
    new = config.to_dict()
    if old is not None and resolved_settings(old) != without_devices(new):
        raise ValueError(f"{store.uri} was built with another config; use a new folder (or delete it) to change settings")
    state["config"] = new
    state["versions"] = _versions()
    state.setdefault("stages", {})
    store.write_json(StoreLayout.STATE, state)


def trainable_groups(store: FamilyStore) -> list[int]:
    """Groups with at least one solved train pair."""
    rows = store.read_table(StoreLayout.PAIRS).to_pylist() if store.exists(StoreLayout.PAIRS) else []
    return sorted({r["group"] for r in rows if r["status"] == "done" and r["split"] == "train"})


def group_training_data(store: FamilyStore, config: BuildConfig, group: int, val_share: float = 0.15) -> dict[str, Any]:
    """Train and validation pairs of one group: a seeded ``val_share`` of its train shapes is held
    out for early stopping. Returns ``{"train": [(src, dst)], "val": [...], "train_ids", "val_ids",
    "features"}``; ``features``: the train shapes' procedural parameters as the teacher's
    confidence finds neighbours by (:func:`proctex.correspond.confidence.param_features`; None
    where the shapes carry none or the confidence is off)."""
    from proctex.correspond.confidence import param_features

    rows = [r for r in store.read_table(StoreLayout.PAIRS).to_pylist() if r["status"] == "done" and r["split"] == "train" and r["group"] == group]
    ids = sorted(r["id"] for r in rows)
    if not ids:
        raise ValueError(f"group {group} has no solved train pairs")
    rng = np.random.default_rng(config.seed + group)
    n_val = max(1, int(round(val_share * len(ids)))) if len(ids) > 2 else 0
    val_ids = set(rng.choice(ids, size=n_val, replace=False).tolist()) if n_val else set()
    train_ids = [i for i in ids if i not in val_ids]
    train_pairs = [read_pair(store, i, group) for i in train_ids]
    val_pairs = [read_pair(store, i, group) for i in sorted(val_ids)] or train_pairs[:1]
    features = None
    if config.train.confidence != "none":  # only the teacher's confidence reads the parameters
        params = {r["id"]: r.get("params") for r in samples(store)}
        features = param_features([json.loads(params.get(i) or "{}") for i in train_ids])
    return {"train": train_pairs, "val": val_pairs, "train_ids": train_ids, "val_ids": sorted(val_ids), "features": features}


def serving_choice(model: Any, data: dict[str, Any]) -> dict[str, Any]:
    """What serves a group at run time (:func:`proctex.correspond.training.choose_serving`): its
    network, the box map or the identity, chosen on the group's held-out train pairs (``data``, from
    :func:`group_training_data`; never ground truth). ``held_out`` False: the group had too few
    shapes to hold one out and the choice was made on a training pair, which favours the network."""
    from proctex.correspond.training import choose_serving, template_extent

    extent = model.template_extent.detach().cpu().numpy() if model.frame == "box" else template_extent(data["train"])
    return {**choose_serving(model, data["val"], extent).to_dict(), "held_out": bool(data["val_ids"])}


def serving_line(serving: dict[str, Any] | None) -> str:
    """One line for a log: what serves the group and the held-out errors it was chosen on."""
    if not serving:
        return "the network serves"
    errs = ", ".join(f"{k} {v:.4f}" for k, v in serving["errors"].items())
    what = {"box": "box map"}.get(serving["serve"], serving["serve"])
    return f"the {what} serves (held-out errors: {errs}{'' if serving.get('held_out', True) else '; no held-out shape'})"


def save_group_model(store: FamilyStore, group: int, result, cfg, data: dict[str, Any]) -> tuple[str, dict[str, Any]]:
    """Write a trained group network to ``models/group_<g>.pt`` (atomically) with its serving choice
    (:func:`serving_choice`); returns its checksum (:func:`proctex.family.store.digest`) and that
    choice, which the train stage records."""
    from proctex.correspond.corrnet import to_bytes

    serving = serving_choice(result.model, data)
    extra = {"group": group, "train_ids": data["train_ids"], "val_ids": data["val_ids"], "best_val": result.best_val, "serving": serving}
    blob = to_bytes(result.model, cfg, extra)
    store.write_bytes(StoreLayout.model(group), blob)
    return digest(blob), serving


VAL_SHARE = 0.15  # of a group's train shapes, held out for early stopping


def fit_group(store: FamilyStore, config: BuildConfig, group: int, rank: int = 0, world: int = 1,
              grad_hook: Callable[[Any], None] | None = None) -> dict[str, Any]:
    """Train group ``group``'s network on its pairs and, on ``rank`` 0, store it; the one train body
    of every executor (in process; each Ray Train worker of a team of ``world``, with ``grad_hook``
    averaging gradients). Returns the group's train record, the same fields whoever trained it:
    ``best_val`` (:func:`proctex.correspond.training.eval_step` of the kept state), ``iterations``,
    ``seconds``, ``train_pairs``, ``val_pairs``, ``sha256`` and ``serving`` (None off rank 0)."""
    from proctex.correspond.training import train

    data = group_training_data(store, config, group, VAL_SHARE)
    t = time.perf_counter()
    result = train(data["train"], data["val"], config.train, rank=rank, world=world, grad_hook=grad_hook, features=data["features"])
    sha, serving = save_group_model(store, group, result, config.train, data) if rank == 0 else (None, None)
    return {"best_val": result.best_val, "iterations": result.iterations, "seconds": round(time.perf_counter() - t, 2),
            "train_pairs": len(data["train"]), "val_pairs": len(data["val"]), "sha256": sha, "serving": serving}


def run_train_batch(store: FamilyStore, config: BuildConfig, groups: list[int], context: Any = None) -> list[dict[str, Any]]:
    """Train and store the networks of ``groups`` in this process; per group its record (:func:`fit_group`)."""
    return [fit_group(store, config, g) for g in groups]


def plan_train(store: FamilyStore, config: BuildConfig, log: Callable[[str], None] = print) -> Plan:
    """The train stage: one ProcCorrNet per trainable group without one yet, a batch per group. A
    resumed build keeps the record of the groups trained before. An executor may set
    ``info["mark"]`` (extra fields for the stage's record)."""
    before = _state(store).get("stages", {}).get("train", {}).get("groups", {})
    groups = trainable_groups(store)
    todo = [g for g in groups if not store.exists(StoreLayout.model(g))]
    trained: dict[Any, Any] = {}
    for g in groups:
        if g not in todo:
            log(f"train: group {g} done already")
            if str(g) in before:
                trained[g] = before[str(g)]
    if not todo and stage_done(store, "train"):
        return Plan("train", [], run_train_batch, finish=lambda results: None, skip="done already")

    def collect(batch: list[int], out: list[dict[str, Any] | None]) -> None:
        for g, m in zip(batch, out):
            if m is not None and "train_pairs" in m:
                log(f"train: group {g}: {m['train_pairs']} train / {m['val_pairs']} val pairs, val {m['best_val']}, {m['seconds']}s; "
                    f"{serving_line(m.get('serving'))}")

    def finish(results: list[list[dict[str, Any] | None]]) -> None:
        for g, m in zip(todo, (m for out in results for m in out)):
            if m is not None:
                trained[g] = {k: v for k, v in m.items() if k not in ("train_pairs", "val_pairs")}
        if todo or not stage_done(store, "train"):
            _mark(store, "train", groups=trained, **plan.info.get("mark", {}))

    plan = Plan("train", [[g] for g in todo], run_train_batch, finish, collect)
    return plan


def stage_train(store: FamilyStore, config: BuildConfig, log: Callable[[str], None] = print) -> None:
    """One ProcCorrNet per non-degenerate group on the train pairs (:func:`plan_train`, here)."""
    run_in_process(plan_train(store, config, log), store, config, log)


def load_models(store: FamilyStore, device: str = "cpu") -> dict[int, Any]:
    """{group: ProcCorrNet} of every stored model. A network whose file holds another group's, or
    whose checksum differs from the train stage's record, is a ``ValueError`` naming the file."""
    from proctex.correspond.corrnet import from_bytes

    recorded = _state(store).get("stages", {}).get("train", {}).get("groups", {})
    models = {}
    for name in store.listdir(StoreLayout.MODELS):
        g = StoreLayout.model_group(name)
        if g is None:
            continue
        where = store.path(StoreLayout.model(g))
        blob = store.read_bytes(StoreLayout.model(g))
        check_digest(blob, (recorded.get(str(g)) or {}).get("sha256"), where)
        models[g], _, extra = from_bytes(blob, device=device, where=where)
        if int(extra.get("group", g)) != g:
            raise ValueError(f"{where}: holds the network of group {extra.get('group')}, not of group {g}")
        models[g].serving = check_serving(extra.get("serving"), where)
    return models


def check_serving(raw: Any, where: str) -> dict[str, Any] | None:
    """A stored serving choice (:func:`serving_choice`) checked: ``{"serve", "template_extent"}``
    with a known ``serve`` and three positive finite extents, else ``ValueError`` naming ``where``;
    None (networks trained before the choice existed: the network serves)."""
    from proctex.correspond.training import SERVING

    if raw is None:
        return None
    ext = raw.get("template_extent") if isinstance(raw, dict) else None
    ok = isinstance(raw, dict) and raw.get("serve") in SERVING and isinstance(ext, list) and len(ext) == 3 and \
        all(isinstance(x, (int, float)) and np.isfinite(x) and x > 0 for x in ext)
    if not ok:
        raise ValueError(f"{where}: damaged serving choice {str(raw)[:200]!r}")
    return raw
