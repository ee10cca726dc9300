"""A family as a unit: build it stage by stage into a store, load it back for transfer (DESIGN §3).

Stages, each idempotent (a rerun skips what is complete and redoes what is missing or failed):

1. ``sample``   — sample the procedural model (or read a folder of samples): ``samples.parquet``, ``meshes/``.
2. ``template`` — the sample nearest the mean parameters: ``template/template.obj``.
3. ``paint``    — parts, groups, UVs and one texture per group: ``template/``.
4. ``pairs``    — the cage correspondence of every (train or test shape, template group):
   ``correspondences/<id>__g<group>.parquet`` and ``pairs.parquet``.
5. ``train``    — one ProcCorrNet per group: ``models/group_<g>.pt``.
6. ``evaluate`` — transfer to the test shapes and measure (:mod:`proctex.evaluate`): ``metrics.json``.

Single process here; the Ray workflows fan the same stage functions out over a cluster.
"""

from __future__ import annotations

import json
import os
import platform
import time
import tomllib
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pyarrow as pa

from .fileio import encode_png
from .meshio import load_mesh_bytes, obj_text
from .parts import analyse, part_mesh, segment
from .shape import Shape
from .store import FamilyStore, StoreLayout

STAGES = ("sample", "template", "paint", "pairs", "train", "evaluate")


# ----------------------------------------------------------------------------------------- config
@dataclass
class BuildConfig:
    """Everything a build needs. Exactly one of ``model`` (built-in name), ``folder`` (samples on
    disk) or ``generator`` (a generator config file) names the family.

    Attributes:
        prompt, group_prompts: what to paint (group prompts keyed by group label or index).
        seed: the family seed; sample ``i`` and pair ``(i, g)`` derive theirs from it.
        n_train, n_test, sampling: how many shapes to sample from a model ("lhs" or "random").
        params: bounds overrides ``{"name": [low, high]}`` for continuous / integer parameters.
        texture_size, painter: template texturing: "surface" (the solid surface painter), "views"
            (the multi-view loop with the offline view painter) or "diffusion" (the multi-view loop
            with a local diffusers model in ``model_dir``).
        views, view_size, paint_hidden, fill: the multi-view loop (cameras on the orbit, their size,
            whether parts hidden from the orbit get views of their own, and how unseen texels are
            filled: "patchmatch" or "surface"). Texels no view saw stay out of the template's
            "already painted" mask, so transfer can detect dis-occlusion.
        model_dir, device, steps: the diffusion painter.
        up: the shapes' up axis ("auto": y for OBJ/glTF files, z otherwise).
        corr_points, cage_level, cage_iterations: the cage solver per pair; cage: other
            :class:`proctex.cage.CageConfig` settings (e.g. ``{"w_rest": 0.3}``).
        train: ProcCorrNet settings (``proctex.corrnet.CorrNetConfig`` fields).
        tessellation: built-in models only: "adaptive" (segments follow each part's size, so most
            parameter changes change a part's connectivity, as real procedural exports do: the
            networks are exercised) or "fixed" (every part keeps its connectivity: the
            same-connectivity shortcut textures it). Stores built before the setting existed are
            "fixed".
        truth: what the evaluation takes as ground truth (:data:`proctex.fidelity.TRUTHS`): "auto"
            (canonical coordinates for built-in models, none otherwise), "vertex-index" (the
            samples share one vertex order: vertex *i* is the same point in every sample; checked
            when evaluating), "canonical" or "none" (the cage solver tracks points; no GT error).
    """

    model: str | None = None
    folder: str | None = None
    generator: str | None = None
    prompt: str = "oak"
    group_prompts: dict[str, str] = field(default_factory=dict)
    seed: int = 0
    n_train: int = 24
    n_test: int = 8
    sampling: str = "lhs"
    params: dict[str, list[float]] = field(default_factory=dict)
    texture_size: int = 512
    painter: str = "surface"
    views: int = 11
    view_size: int = 512
    paint_hidden: bool = True
    fill: str = "patchmatch"
    model_dir: str | None = None
    device: str = "cpu"
    steps: int = 20
    up: str = "auto"
    corr_points: int = 2000
    cage_level: int = 1
    cage_iterations: int = 300
    train: dict[str, Any] = field(default_factory=dict)
    cage: dict[str, Any] = field(default_factory=dict)
    tessellation: str = "adaptive"
    truth: str = "auto"

    def validate(self) -> "BuildConfig":
        named = [x for x in (self.model, self.folder, self.generator) if x]
        if len(named) != 1:
            raise ValueError("name exactly one of model, folder or generator")
        if self.model:
            from .models import get_model

            get_model(self.model)  # unknown names raise ValueError listing the models
        if self.folder and not os.path.isdir(self.folder):
            raise ValueError(f"folder {self.folder!r} not found")
        if self.generator and not os.path.isfile(self.generator):
            raise ValueError(f"generator config {self.generator!r} not found")
        if not isinstance(self.prompt, str):
            raise ValueError("prompt must be a string")
        if self.n_train < 2 or self.n_test < 0:
            raise ValueError(f"need n_train >= 2 and n_test >= 0, got {self.n_train}, {self.n_test}")
        if self.sampling not in ("lhs", "random"):
            raise ValueError(f"sampling must be lhs or random, got {self.sampling!r}")
        if self.texture_size < 16:
            raise ValueError(f"texture_size must be >= 16, got {self.texture_size}")
        if self.painter not in ("surface", "views", "diffusion"):
            raise ValueError(f"painter must be surface, views or diffusion, got {self.painter!r}")
        if self.views < 3 or self.view_size < 16 or self.steps < 1:
            raise ValueError("views must be >= 3, view_size >= 16 and steps >= 1")
        if self.fill not in ("patchmatch", "surface"):
            raise ValueError(f"fill must be patchmatch or surface, got {self.fill!r}")
        if self.painter == "diffusion" and not (self.model_dir and os.path.isdir(self.model_dir)):
            raise ValueError(f"painter 'diffusion' needs model_dir, a local diffusers model folder (got {self.model_dir!r})")
        if self.up not in ("auto", "x", "y", "z"):
            raise ValueError(f"up must be auto, x, y or z, got {self.up!r}")
        if self.tessellation not in ("adaptive", "fixed"):
            raise ValueError(f"tessellation must be adaptive or fixed, got {self.tessellation!r}")
        from .fidelity import TRUTHS

        if self.truth not in TRUTHS:
            raise ValueError(f"truth must be one of {', '.join(TRUTHS)}, got {self.truth!r}")
        if self.truth == "canonical" and not self.model:
            raise ValueError("truth 'canonical' needs a built-in model (canonical coordinates)")
        if self.corr_points < 100 or self.cage_iterations < 1 or not 0 <= self.cage_level <= 4:
            raise ValueError("corr_points >= 100, cage_iterations >= 1 and cage_level in [0, 4] required")
        self.cage_config()
        return self

    def cage_config(self):
        """The cage solver's settings of this build (:class:`proctex.cage.CageConfig`):
        ``cage_level``, ``cage_iterations`` and the ``cage`` overrides; ``ValueError`` on bad ones."""
        from dataclasses import fields as dc_fields

        from .cage import CageConfig

        if not isinstance(self.cage, dict):
            raise ValueError(f"cage must be an object of cage solver settings, got {type(self.cage).__name__}")
        clash = sorted(set(self.cage) & {"level", "iterations"})
        if clash:
            raise ValueError(f"set the cage's {', '.join(clash)} with cage_level / cage_iterations, not in cage")
        known = {f.name for f in dc_fields(CageConfig)}
        unknown = sorted(set(self.cage) - known)
        if unknown:
            raise ValueError(f"unknown cage settings {unknown}; known: {sorted(known - {'level', 'iterations'})}")
        try:
            return CageConfig(level=self.cage_level, iterations=self.cage_iterations, **self.cage).validate()
        except TypeError as exc:
            raise ValueError(f"bad cage settings: {exc}") from exc

    @staticmethod
    def from_dict(data: dict[str, Any]) -> "BuildConfig":
        known = {f.name for f in fields(BuildConfig)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown config keys: {', '.join(unknown)} (known: {', '.join(sorted(known))})")
        return BuildConfig(**data).validate()

    @staticmethod
    def read_settings(path: str | os.PathLike) -> dict[str, Any]:
        """The settings of a JSON or TOML config file, unvalidated (relative paths made relative to
        the file); a missing or unparsable file is a ``ValueError``."""
        p = Path(path)
        if not p.is_file():
            raise ValueError(f"{path}: config file not found")
        try:
            data = tomllib.loads(p.read_text()) if p.suffix == ".toml" else json.loads(p.read_text())
        except (json.JSONDecodeError, tomllib.TOMLDecodeError) as exc:
            raise ValueError(f"{path}: cannot parse config ({exc})") from exc
        if not isinstance(data, dict):
            raise ValueError(f"{path}: a config must be an object of settings")
        for key in ("folder", "generator", "model_dir"):
            if data.get(key) and not os.path.isabs(data[key]):
                data[key] = str((p.parent / data[key]).resolve())
        return data

    @staticmethod
    def from_file(path: str | os.PathLike) -> "BuildConfig":
        """Read a JSON or TOML config (keys as the attributes; relative paths are relative to the file)."""
        return BuildConfig.from_dict(BuildConfig.read_settings(path))


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


def _model(config: BuildConfig):
    from .models import get_model
    from .sources import load_generator

    model = load_generator(config.generator) if config.generator else get_model(config.model, tessellation=config.tessellation)
    if config.params:
        model.space = _restricted(model.space, config.params)
    return model


def _restricted(space, bounds: dict[str, list[float]]):
    from .params import ParamSpace, ParamSpec

    specs = []
    for s in space.specs:
        if s.name in bounds:
            lo, hi = bounds[s.name]
            if s.kind not in ("continuous", "integer"):
                raise ValueError(f"bounds given for {s.name!r}, which is a {s.kind} parameter")
            if not (s.low <= lo <= hi <= s.high):
                raise ValueError(f"bounds for {s.name!r} must lie within [{s.low}, {s.high}], got [{lo}, {hi}]")
            d = s.to_dict()
            d.update(low=lo, high=hi, default=min(max(d["default"], lo), hi))
            specs.append(ParamSpec.from_dict(d))
        else:
            specs.append(s)
    unknown = set(bounds) - {s.name for s in space.specs}
    if unknown:
        raise ValueError(f"bounds for unknown parameters: {', '.join(sorted(unknown))}")
    return ParamSpace(tuple(specs))


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
    if config.folder:
        src = _folder(config.folder)
        return [SampleJob(i, s.id.replace("/", "_"), s.split, src.params(i)) for i, s in enumerate(src.samples)]
    model = _model(config)
    params = model.space.sample(config.n_train + config.n_test, seed=config.seed, method=config.sampling)
    return [SampleJob(i, f"s{i:04d}", "train" if i < config.n_train else "test", p) for i, p in enumerate(params)]


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
    shape = _folder(config.folder).load(job.index) if config.folder else _model(config).generate(job.params)
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


def stage_sample(store: FamilyStore, config: BuildConfig, log: Callable[[str], None] = print) -> None:
    """Sample shapes (or read the folder) into ``meshes/`` and ``samples.parquet``."""
    if stage_done(store, "sample"):
        log("sample: done already")
        return
    rows = [run_sample_job(store, config, job) for job in sample_jobs(config)]
    finish_sample_stage(store, rows)
    log(f"sample: {len(rows)} shapes")


def samples(store: FamilyStore) -> list[dict[str, Any]]:
    return store.read_table(StoreLayout.SAMPLES).to_pylist()


def _read_obj(store: FamilyStore, rel: str) -> Shape:
    shape, _ = load_mesh_bytes(store.read_bytes(rel), rel)
    return shape


def load_sample(store: FamilyStore, row: dict[str, Any], config: BuildConfig | None = None) -> Shape:
    """A sample as a :class:`Shape`. Model families regenerate it from its parameters (exact, with
    labels and canonical coordinates); folder families read the stored mesh."""
    params = json.loads(row["params"])
    if config is not None and not config.folder:
        shape = _model(config).generate(params)
        shape.source = row["mesh"]
        return shape
    shape = _read_obj(store, row["mesh"])
    shape.params = params
    return shape


def stage_template(store: FamilyStore, config: BuildConfig, log: Callable[[str], None] = print) -> None:
    """Pick the train sample nearest the mean parameters."""
    if stage_done(store, "template"):
        log("template: done already")
        return
    from .params import infer_space, select_template

    rows = [r for r in samples(store) if r["split"] == "train"]
    params = [json.loads(r["params"]) for r in rows]
    space = infer_space(params) if config.folder else _model(config).space
    i = select_template(space, params) if len(space) else 0
    store.write_bytes(StoreLayout.TEMPLATE_MESH, store.read_bytes(rows[i]["mesh"]))
    _mark(store, "template", id=rows[i]["id"], params=params[i])
    log(f"template: {rows[i]['id']}")


def up_axis(config: BuildConfig) -> str:
    if config.up != "auto":
        return config.up
    return "y" if config.folder else "z"


def stage_paint(store: FamilyStore, config: BuildConfig, log: Callable[[str], None] = print) -> None:
    """Parts, groups, UVs and textures of the template into ``template/``."""
    if stage_done(store, "paint"):
        log("paint: done already")
        return
    import tempfile

    from .paint import paint_template, write_textured

    template = load_template_shape(store, config)
    grouping = analyse(template, seed=config.seed)
    tex = paint_template(template, grouping, config.prompt, config.group_prompts, painter=config.painter, size=config.texture_size,
                         seed=config.seed, up=up_axis(config), views=config.views, view_size=config.view_size,
                         complete_hidden=config.paint_hidden, fill=config.fill, model_dir=config.model_dir, device=config.device,
                         steps=config.steps, on_view=lambda k, n, st: log(f"paint: view {k + 1}/{n}, {st['texels_updated']} texels"))
    from .template import Template

    labels = [g.label for g in tex.groups]
    record = Template(template, grouping, tex.uv.corner_uv, tex.uv.face_group, [g.uint8() for g in tex.groups],
                      [g.label or f"group_{g.group}" for g in tex.groups], labels, tex.painted_masks, tex.observed_masks)
    with tempfile.TemporaryDirectory() as tmp:
        summary = write_textured(tex, tmp, up=up_axis(config))
        textures = {StoreLayout.texture(g, label) for g, label in enumerate(labels)}  # the record writes those
        for name in sorted(os.listdir(tmp)):
            if StoreLayout.template_file(name) not in textures:
                store.write_bytes(StoreLayout.template_file(name), (Path(tmp) / name).read_bytes())
    record.save(store)
    _mark(store, "paint", coverage=summary["coverage"]["share"], groups=len(grouping.groups), seconds=round(tex.seconds, 3))
    log(f"paint: {len(grouping.groups)} groups, unpainted visible pixels {100 * summary['coverage']['share']:.3f}%")


def load_template_shape(store: FamilyStore, config: BuildConfig | None = None) -> Shape:
    """The template shape (regenerated from its parameters for model families, see :func:`load_sample`)."""
    config = config if config is not None else stored_config(store)
    if not config.folder:
        params = _state(store)["stages"]["template"]["params"]
        shape = _model(config).generate(params)
        shape.source = StoreLayout.TEMPLATE_MESH
        return shape
    return _read_obj(store, StoreLayout.TEMPLATE_MESH)


#: Settings whose default changed after stores without them were written: their value then.
LEGACY_SETTINGS = {"tessellation": "fixed",
                   # the cage solver before the box pre-alignment, face normals, rest term and best iterate
                   "cage": {"prealign": "icp", "normal_target": "vertex", "keep_best": False, "w_rest": 0.0}}


def _with_legacy(settings: dict[str, Any]) -> dict[str, Any]:
    """A stored config's settings with the values older stores were built with filled in."""
    return {**LEGACY_SETTINGS, **settings}


def stored_config(store: FamilyStore) -> BuildConfig:
    state = _state(store)
    if "config" not in state:
        raise ValueError(f"{store.uri}: not a ProcTex family (no family.json with a config)")
    return BuildConfig.from_dict(_with_legacy(state["config"]))


def load_template(store: FamilyStore, config: BuildConfig | None = None):
    """The stored :class:`proctex.template.Template` (its mesh regenerated for model families)."""
    from .template import Template

    config = config if config is not None else stored_config(store)
    return Template.load(store, load_template_shape(store, config), seed=config.seed)


def load_assets(store: FamilyStore):
    """The template ready for transfer (:class:`proctex.assets.TemplateAssets`), from the store."""
    return load_template(store).assets()


def solve_pair(shape: Shape, assets, group: int, config: BuildConfig, seed: int) -> dict[str, Any] | None:
    """Cage correspondence of one (shape, template group): the training pair and its record."""
    from .correspond import correspond_parts
    from .assign import assign_parts, choose_part, representative_frame

    seg = segment(shape)
    a = choose_part(assign_parts(shape, seg, assets), group)
    if a is None:
        return None
    v, f = part_mesh(shape, seg.parts[a.part])
    vn = representative_frame(v, a)
    ga = assets.groups[group]
    cage = config.cage_config()
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


def stage_pairs(store: FamilyStore, config: BuildConfig, log: Callable[[str], None] = print, splits: tuple[str, ...] = ("train", "test")) -> None:
    """Cage pairs for every (shape, non-degenerate template group); skips pairs already complete."""
    assets = load_assets(store)
    jobs = pair_jobs(store, config, assets, splits)
    records = pair_records(store, jobs)
    todo = [j for j in jobs if not pair_complete(records.get(j.key))]
    if not todo and stage_done(store, "pairs"):
        log("pairs: done already")
        return
    t0, n, shape, shape_id = time.perf_counter(), 0, None, None
    for k, job in enumerate(todo):
        if shape_id != job.row["id"]:
            shape, shape_id = load_sample(store, job.row, config), job.row["id"]
        records[job.key] = run_pair_job(store, config, assets, job, shape)
        n += 1
        if k + 1 == len(todo) or todo[k + 1].row["id"] != shape_id:
            write_pairs_index(store, jobs, records)
            log(f"pairs: {shape_id} ({n}/{len(todo)} solved, {time.perf_counter() - t0:.0f}s)")
    finish_pairs_stage(store, jobs, records, log)


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
    new = asdict(config)
    if old is not None:  # settings added since that build count at their defaults (or their value then)
        old = {**asdict(BuildConfig()), **_with_legacy(old)}
    if old is not None and old != new:
        raise ValueError(f"{store.uri} was built with another config; use a new folder (or delete it) to change settings")
    state["config"] = new
    state["versions"] = _versions()
    state.setdefault("stages", {})
    store.write_json(StoreLayout.STATE, state)


def corrnet_config(config: BuildConfig):
    """The ProcCorrNet settings of a build (``config.train`` over the defaults, the family seed)."""
    from .corrnet import CorrNetConfig

    return CorrNetConfig.from_dict({**config.train, "seed": config.train.get("seed", config.seed)})


def trainable_groups(store: FamilyStore) -> list[int]:
    """Groups with at least one solved train pair."""
    rows = store.read_table(StoreLayout.PAIRS).to_pylist() if store.exists(StoreLayout.PAIRS) else []
    return sorted({r["group"] for r in rows if r["status"] == "done" and r["split"] == "train"})


def group_training_data(store: FamilyStore, config: BuildConfig, group: int, val_share: float = 0.15) -> dict[str, Any]:
    """Train and validation pairs of one group: a seeded ``val_share`` of its train shapes is held
    out for early stopping. Returns ``{"train": [(src, dst)], "val": [...], "train_ids", "val_ids"}``."""
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
    return {"train": train_pairs, "val": val_pairs, "train_ids": train_ids, "val_ids": sorted(val_ids)}


def save_group_model(store: FamilyStore, group: int, result, cfg, data: dict[str, Any]) -> None:
    """Write a trained group network to ``models/group_<g>.pt`` (atomically)."""
    from .corrnet import to_bytes

    extra = {"group": group, "train_ids": data["train_ids"], "val_ids": data["val_ids"], "best_val": result.best_val}
    store.write_bytes(StoreLayout.model(group), to_bytes(result.model, cfg, extra))


def stage_train(store: FamilyStore, config: BuildConfig, log: Callable[[str], None] = print, val_share: float = 0.15) -> None:
    """One ProcCorrNet per non-degenerate group on the train pairs (a share held out for early stopping)."""
    from .corrnet import train

    cfg = corrnet_config(config)
    # A resumed build keeps the record of the groups trained before.
    before = _state(store).get("stages", {}).get("train", {}).get("groups", {})
    trained: dict[Any, Any] = {}
    fresh = False
    for g in trainable_groups(store):
        if store.exists(StoreLayout.model(g)):
            log(f"train: group {g} done already")
            if str(g) in before:
                trained[g] = before[str(g)]
            continue
        data = group_training_data(store, config, g, val_share)
        t = time.perf_counter()
        result = train(data["train"], data["val"], cfg)
        save_group_model(store, g, result, cfg, data)
        trained[g] = {"best_val": result.best_val, "iterations": result.iterations, "seconds": round(time.perf_counter() - t, 2)}
        fresh = True
        log(f"train: group {g}: {len(data['train'])} train / {len(data['val'])} val pairs, val {result.best_val}, {trained[g]['seconds']}s")
    if fresh or not stage_done(store, "train"):
        _mark(store, "train", groups=trained)


def load_models(store: FamilyStore, device: str = "cpu") -> dict[int, Any]:
    """{group: ProcCorrNet} of every stored model."""
    from .corrnet import from_bytes

    models = {}
    for name in store.listdir(StoreLayout.MODELS):
        g = StoreLayout.model_group(name)
        if g is None:
            continue
        models[g], _, _ = from_bytes(store.read_bytes(StoreLayout.model(g)), device=device, where=store.path(StoreLayout.model(g)))
    return models


# ------------------------------------------------------------------------------------------ edits
def _group_entry(store: FamilyStore, group: int | str) -> dict[str, Any]:
    summary = store.read_json(StoreLayout.PAINT)
    for g in summary["groups"]:
        if str(g["group"]) == str(group) or (g["label"] and g["label"] == str(group)):
            return g
    names = [str(g["group"]) + (f" ({g['label']})" if g["label"] else "") for g in summary["groups"]]
    raise ValueError(f"unknown group {group!r}; the template's groups are: {', '.join(names)}")


def refresh_template_glb(store: FamilyStore) -> None:
    """Rewrite ``template/textured.glb`` from the stored mesh, UVs and group PNGs."""
    from .export import glb_bytes
    config = stored_config(store)
    template = load_template_shape(store, config)
    uv = store.read_arrays(StoreLayout.UV)
    summary = store.read_json(StoreLayout.PAINT)
    pngs = [store.read_bytes(StoreLayout.texture(g["group"], g["label"])) for g in summary["groups"]]
    names = [g["label"] or f"group_{g['group']}" for g in summary["groups"]]
    store.write_bytes(StoreLayout.TEMPLATE_GLB, glb_bytes(template.vertices, template.faces, uv["corner_uv"], uv["face_group"], pngs, names=names,
                                                         up=up_axis(config)))


def edit_texture(
    texture: np.ndarray,
    group: int,
    label: str | None = None,
    hue: float = 0.0,
    saturation: float = 1.0,
    value: float = 1.0,
    prompt: str | None = None,
    template: Shape | None = None,
    rep_faces: np.ndarray | None = None,
    rep_corner_uv: np.ndarray | None = None,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray | None, dict[str, Any]]:
    """One group texture after an edit: re-painted with ``prompt`` first (the surface painter,
    ``seed``), then HSV-shifted (``hue`` degrees, ``saturation`` and ``value`` scales). Pure: the
    store is not touched (:func:`edit_group` persists, the service previews with it).

    Args:
        texture: (H, W, 3) uint8 or float in [0, 1], the group's current texture.
        group, label: the group (the painter takes them as hints).
        template, rep_faces, rep_corner_uv: needed for a re-paint only: the template shape, the face
            ids of the group's representative part and their (f, 3, 2) UVs.

    Returns:
        ``(texture, painted, record)``: (H, W, 3) float32 in [0, 1]; the (H, W) bool mask of the texels
        the re-paint coloured (None without a prompt); the edit record (``group``, ``prompt``,
        ``hsv`` as given, without the operations that were no-ops).
    """
    from .edit import shift_hsv

    t = np.asarray(texture)
    tex = (t.astype(np.float32) / 255) if t.dtype == np.uint8 else t.astype(np.float32)
    tex = np.ascontiguousarray(tex[..., :3])
    record: dict[str, Any] = {"group": int(group)}
    painted = None
    if prompt is not None:
        from .paint import shape_frame
        from .painters import SurfacePainter
        from .uv import pad_seams, texel_map

        if template is None or rep_faces is None or rep_corner_uv is None:
            raise ValueError("a re-paint needs the template, its representative faces and their UVs")
        faces = template.faces[np.asarray(rep_faces)]
        tm = texel_map(template.vertices, faces, np.asarray(rep_corner_uv), tex.shape[0], tex.shape[1])
        center, scale = shape_frame(template)
        colors = SurfacePainter(prompt, seed=seed).paint((tm.points - center) / scale, tm.normals, group=int(group), label=label)
        fresh = np.full_like(tex, 0.5)
        fresh[tm.ij[:, 0], tm.ij[:, 1]] = colors
        tex, painted = pad_seams(fresh, tm.mask, 8)
        tex = np.asarray(tex, dtype=np.float32)
        record["prompt"] = prompt
    if hue or saturation != 1.0 or value != 1.0:
        tex = shift_hsv(np.clip(tex, 0, 1), hue_deg=hue, saturation=saturation, value=value)
        record["hsv"] = [hue, saturation, value]
    return tex, painted, record


def edit_group(
    store: FamilyStore,
    group: int | str,
    hue: float = 0.0,
    saturation: float = 1.0,
    value: float = 1.0,
    logo: str | None = None,
    at: tuple[float, float] = (0.5, 0.5),
    size: tuple[float, float] = (0.25, 0.25),
    rotation: float = 0.0,
    opacity: float = 1.0,
    prompt: str | None = None,
) -> dict[str, Any]:
    """Edit one group's template texture in the store; every later transfer or bake uses it.

    Operations, applied in this order when several are given: re-paint with a new ``prompt`` (the
    surface painter, the family's seed), HSV shift (``hue`` degrees, ``saturation`` and ``value``
    scales) — both by :func:`edit_texture` —, and placing an image file (``logo``) centred at UV
    ``at`` with UV ``size``, ``rotation`` (degrees) and ``opacity``. Returns the edit record appended
    to ``template/paint.json``.
    """
    import io

    from PIL import Image

    from .edit import load_overlay, place_image
    entry = _group_entry(store, group)
    gi = int(entry["group"])
    rel = StoreLayout.texture(gi, entry["label"])
    tex = np.asarray(Image.open(io.BytesIO(store.read_bytes(rel))).convert("RGB"))
    template = rep_faces = rep_uv = None
    config = stored_config(store)
    if prompt is not None:  # the re-paint needs the template's geometry
        template = load_template_shape(store, config)
        grouping = analyse(template, seed=config.seed)
        rep_faces = grouping.parts[grouping.groups[gi].representative].faces
        rep_uv = store.read_arrays(StoreLayout.UV)["corner_uv"][rep_faces]
    tex, painted, record = edit_texture(tex, gi, entry["label"], hue, saturation, value, prompt,
                                        template=template, rep_faces=rep_faces, rep_corner_uv=rep_uv, seed=config.seed)
    if painted is not None:
        masks = store.read_arrays(StoreLayout.PAINTED) if store.exists(StoreLayout.PAINTED) else None
        if masks is not None:  # the whole group is painted now
            masks[f"g{gi}"] = painted
            masks[f"o{gi}"] = painted
            store.write_arrays(StoreLayout.PAINTED, **masks)
    if logo is not None:
        tex = place_image(tex, load_overlay(logo), at, size, rotation_deg=rotation, opacity=opacity)
        record["logo"] = {"file": os.path.basename(logo), "at": list(at), "size": list(size), "rotation": rotation, "opacity": opacity}
    if len(record) == 1:
        raise ValueError("no edit given (prompt, hue/saturation/value or logo)")
    store.write_bytes(rel, encode_png(tex))
    summary = store.read_json(StoreLayout.PAINT)
    for g in summary["groups"]:
        if g["group"] == gi and "prompt" in record:
            g["prompt"] = record["prompt"]
    summary.setdefault("edits", []).append(record)
    store.write_json(StoreLayout.PAINT, summary)
    refresh_template_glb(store)
    return record
