"""The ``pairs`` stage: the cage correspondence of every (train or test shape, template group)."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
import pyarrow as pa

from proctex.build.plan import Plan
from proctex.build.groupdata import VAL_SHARE, plain_groups
from proctex.correspond.dense import correspond_parts, deform
from proctex.geometry.parts import part_mesh, segment
from proctex.geometry.shape import Shape
from proctex.store.config import BuildConfig
from proctex.store.family import Family
from proctex.store.layout import FamilyStore, StoreLayout
from proctex.store.samples import held_out_split, load_sample, pair_seed, part_digest, samples, write_pair_vertices
from proctex.store.state import FamilyState, stage_done
from proctex.transfer.assets import load_assets
from proctex.transfer.assign import assign_parts, choose_part, representative_part


def shape_assignment(shape: Shape, assets) -> tuple[Any, list[Any]]:
    """``(segmentation, part assignments)`` of ``shape`` to the template ``assets``
    (:func:`proctex.transfer.assign.assign_parts`), computed once per shape and template and kept
    on the shape: a batch solves every group of one shape, and a template of hundreds of groups
    (a set of trees) segmented and assigned a shape of thousands of parts again for each one.
    Computed again when the shape's arrays or the assets object were replaced."""
    cached = shape.derived.get("assignment")
    if cached is not None and cached[0] is assets and cached[1] is shape.faces and cached[2] is shape.vertices:
        return cached[3], cached[4]
    seg = segment(shape)
    assignment = assign_parts(shape, seg, assets)
    shape.derived["assignment"] = (assets, shape.faces, shape.vertices, seg, assignment)
    return seg, assignment


def pair_input(shape: Shape, assets, group: int) -> tuple[int, np.ndarray, np.ndarray] | None:
    """The part of ``shape`` that maps onto template ``group``: ``(part index, vertices (j, 3),
    faces (k, 3))`` (mirrored members kept wound outward), or None when the shape lacks the group."""
    seg, assignment = shape_assignment(shape, assets)
    a = choose_part(assignment, group)
    if a is None:
        return None
    vn, f = representative_part(*part_mesh(shape, seg.parts[a.part]), a)  # winding kept outward under a mirror
    return a.part, vn, f


#: Test parts with more vertices keep no vertex map (float64, 24 bytes a vertex: 6 MB at most a
#: pair); the evaluation's tracker solves their pairs again instead.
MAX_VERTEX_MAP = 250_000


def pair_result(part: int, res, vertices: np.ndarray | None = None, faces: np.ndarray | None = None) -> dict[str, Any]:
    """A solved cage correspondence (:class:`proctex.correspond.dense.PartCorrespondence`) as the
    training pair and its record; with the source part's ``vertices (j, 3)`` and ``faces``, also
    where the correspondence sends those vertices (``mapped``, the template's normalised frame) and
    the part's :func:`part_digest`."""
    mapped = None
    if vertices is not None and faces is not None:
        mapped = {"vertices": deform(res, vertices, np.zeros(3), 1.0), "digest": part_digest(vertices, faces)}
    return {
        "part": part,
        "mapped": mapped,
        "src": res.source_points.astype(np.float32),
        "dst": res.points.astype(np.float32),  # template normalised frame (the representative is stored normalised)
        "face": res.faces.astype(np.int32),
        "residual": res.residual,
        "chamfer": res.chamfer,
        "converged": res.converged,
        "iterations": res.iterations,
        "seconds": res.seconds,
    }


def solve_pair(shape: Shape, assets, group: int, config: BuildConfig, seed: int, vertex_map: bool = False) -> dict[str, Any] | None:
    """Cage correspondence of one (shape, template group): the training pair and its record; with
    ``vertex_map``, also where it sends the part's vertices (parts of at most
    :data:`MAX_VERTEX_MAP` vertices; :func:`pair_result`)."""
    inp = pair_input(shape, assets, group)
    if inp is None:
        return None
    part, vn, f = inp
    ga = assets.groups[group]
    res = correspond_parts(vn, f, ga.vertices, ga.faces, method="cage", n_points=config.corr_points, seed=seed, cage=config.cage)
    return pair_result(part, res, vn, f) if vertex_map and len(vn) <= MAX_VERTEX_MAP else pair_result(part, res)


@dataclass
class PairJob:
    """One cage correspondence to solve: sample ``index`` (its ``samples.parquet`` row) and template
    ``group``; ``version``: the family's version it was planned at (a worker keys its cached template
    on it without reading ``family.json``; "" where unknown)."""

    index: int
    row: dict[str, Any]
    group: int
    version: str = ""

    @property
    def key(self) -> tuple[str, int]:
        return (self.row["id"], self.group)


def pair_jobs(store: FamilyStore, config: BuildConfig, assets=None, splits: tuple[str, ...] = ("train", "test")) -> list[PairJob]:
    """Every (shape of ``splits``, non-degenerate template group) pair, in sample order."""
    assets = assets if assets is not None else load_assets(store)
    groups = [g.group for g in assets.groups if not g.degenerate]
    version = Family.open(store).version
    return [PairJob(i, r, g, version) for i, r in enumerate(samples(store)) if r["split"] in splits for g in groups]


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


def pair_complete(record: dict[str, Any] | None, settled: Any = ()) -> bool:
    """A pair needs no more work: solved, the shape lacks the group, or skipped (a train pair of a
    group whose plain map fits) while its group is among ``settled``."""
    if record is None:
        return False
    return record.get("status") in ("done", "absent") or (record.get("status") == "skipped" and record.get("group") in settled)


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
        # a test pair keeps where it sends its part's vertices: the evaluation's cage tracker reads them
        pair = solve_pair(shape, assets, g, config, pair_seed(config, job.index, g), vertex_map=job.row["split"] == "test")
        status = "done" if pair is not None else "absent"
        error = ""
    except (ValueError, RuntimeError) as exc:
        pair, status, error = None, "failed", str(exc)
    return write_pair(store, job, old, pair, status, error, time.perf_counter() - t)


def write_pair(store: FamilyStore, job: PairJob, old: dict[str, Any] | None, pair: dict[str, Any] | None, status: str, error: str, seconds: float) -> dict[str, Any]:
    """Store one pair's outcome (:func:`pair_result` or None, its status and error): the
    correspondence Parquet file first, then its JSON record, both atomic. Returns the record."""
    sid, g = job.key
    rel = StoreLayout.pair_record(sid, g)
    if pair is not None and pair["mapped"] is not None:
        write_pair_vertices(store, sid, g, **pair["mapped"])
    if pair is not None:
        store.write_table(
            StoreLayout.pair(sid, g),
            {
                "sx": pair["src"][:, 0],
                "sy": pair["src"][:, 1],
                "sz": pair["src"][:, 2],
                "tx": pair["dst"][:, 0],
                "ty": pair["dst"][:, 1],
                "tz": pair["dst"][:, 2],
                "face": pair["face"],
            },
        )
    record = {
        "id": sid,
        "split": job.row["split"],
        "group": g,
        "status": status,
        "error": error,
        "part": -1 if pair is None else int(pair["part"]),
        "residual": None if pair is None else float(pair["residual"]),
        "chamfer": None if pair is None else float(pair["chamfer"]),
        "converged": bool(pair and pair["converged"]),
        "iterations": 0 if pair is None else int(pair["iterations"]),
        "seconds": seconds,
        "attempts": 1 + (old or {}).get("attempts", 0),
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
            rows.append({**r, "residual": float("nan") if r["residual"] is None else r["residual"], "chamfer": float("nan") if r["chamfer"] is None else r["chamfer"]})
    store.write_table(StoreLayout.PAIRS, pa.Table.from_pylist(rows))


def finish_pairs_stage(
    store: FamilyStore, jobs: list[PairJob], records: dict[tuple[str, int], dict[str, Any]], log: Callable[[str], None] = print, settled: dict[int, dict[str, float]] | None = None
) -> dict[str, Any] | None:
    """Write the index; returns the stage's record when every job is complete (skipped pairs of the
    ``settled`` groups included; the record keeps those groups and their plain maps' errors), else None."""
    write_pairs_index(store, jobs, records)
    settled = settled or {}
    failed = sum(r["status"] == "failed" for r in records.values())
    missing = sum(not pair_complete(records.get(job.key), settled) and records.get(job.key, {}).get("status") != "failed" for job in jobs)
    if failed or missing:
        log(f"pairs: {failed} failed, {missing} not run (rerun to retry)")
        return None
    skipped = sum(r["status"] == "skipped" for r in records.values())
    return {"pairs": len(records), "solved": len(records) - skipped, "skipped": skipped, "settled": {str(g): {k: round(v, 6) for k, v in e.items()} for g, e in settled.items()}}


INDEX_EVERY = 5.0  # seconds between rewrites of pairs.parquet while pairs arrive


# Template assets per (store, build stamp), kept between batches by a process that runs pair batches
# without them (a Ray worker).
_ASSETS: dict[tuple[str, str], Any] = {}


def cached_assets(store: FamilyStore, version: str = "") -> Any:
    """The store's template assets, loaded once per process and family version
    (:attr:`Family.version`; ``version``: the one the jobs were planned at, else read here)."""
    key = (store.uri, version or Family.open(store).version)
    if key not in _ASSETS:
        _ASSETS.clear()
        _ASSETS[key] = load_assets(store)
    return _ASSETS[key]


def solves_here(config: BuildConfig) -> bool:
    """Whether the pairs stage prepares its pairs in the workers and solves them in the process
    that plans it, every group's pairs in one cage program on its GPU (:func:`_prepare_plan`):
    ``cage.batch`` 0 with the solver on CUDA, present here. Worker processes that share one GPU
    take turns on it (a context each, time-sliced): batches solved in 8 or 16 workers took the sofa
    export's pairs stage 48.5-55.3 s on an H200 machine, one pair at a time on its CPUs 23.6 s."""
    if config.cage.batch or config.cage.device != "cuda":
        return False
    import torch

    return bool(torch.cuda.is_available())


def pair_batch_size(config: BuildConfig) -> int:
    """Shapes whose pairs one worker's batch solves together, template group by template group,
    in one cage program each (:func:`proctex.correspond.dense.correspond_parts_batch`):
    ``cage.batch``, else 1 (each pair alone, the single solver; :func:`solves_here` batches a
    whole group instead)."""
    return int(config.cage.batch) or 1


def run_pair_batch(store: FamilyStore, config: BuildConfig, jobs: list[PairJob], context: Any = None) -> list[dict[str, Any]]:
    """Solve and store a batch of cage pairs (one shape's, or several shapes' where
    :func:`pair_batch_size` is over 1: each loaded once) with the template assets ``context``
    (loaded here when None); their records, in the jobs' order."""
    assets = context if context is not None else cached_assets(store, jobs[0].version if jobs else "")
    shapes: dict[str, Shape | None] = {}
    for job in jobs:
        if job.row["id"] not in shapes:
            try:
                shapes[job.row["id"]] = load_sample(store, job.row, config)
            except (ValueError, RuntimeError):
                shapes[job.row["id"]] = None  # run_pair_job loads it again and records the failure
    if pair_batch_size(config) > 1:
        return _run_batched(store, config, assets, jobs, shapes)
    return [run_pair_job(store, config, assets, job, shapes[job.row["id"]]) for job in jobs]


def _run_batched(store: FamilyStore, config: BuildConfig, assets, jobs: list[PairJob], shapes: dict[str, Shape | None]) -> list[dict[str, Any]]:
    """:func:`run_pair_batch`'s pairs solved group by group in one cage program each; a pair whose
    shape, part or batch fails is solved alone by :func:`run_pair_job` (which records its error)."""
    from proctex.correspond.dense import correspond_parts_batch

    out: dict[tuple[str, int], dict[str, Any]] = {}
    by_group: dict[int, list[tuple[PairJob, dict[str, Any] | None, int, np.ndarray, np.ndarray]]] = {}
    for job in jobs:
        rel = StoreLayout.pair_record(*job.key)
        old = store.read_json(rel) if store.exists(rel) else None
        if pair_complete(old):
            out[job.key] = old
            continue
        shape = shapes[job.row["id"]]
        try:
            inp = pair_input(shape, assets, job.group) if shape is not None else False
        except (ValueError, RuntimeError):
            inp = False
        if inp is None:
            out[job.key] = write_pair(store, job, old, None, "absent", "", 0.0)
        elif inp is False:
            out[job.key] = run_pair_job(store, config, assets, job, shape)
        else:
            by_group.setdefault(job.group, []).append((job, old, *inp))
    for g, rows in by_group.items():
        ga = assets.groups[g]
        t = time.perf_counter()
        try:
            res = correspond_parts_batch([(vn, f, pair_seed(config, job.index, g)) for job, _, _, vn, f in rows], ga.vertices, ga.faces, n_points=config.corr_points, cage=config.cage)
        except (ValueError, RuntimeError):
            res = None  # each pair alone, each failure recorded
        seconds = (time.perf_counter() - t) / len(rows)
        for k, (job, old, part, vn, f) in enumerate(rows):
            if res is None:
                out[job.key] = run_pair_job(store, config, assets, job, shapes[job.row["id"]])
                continue
            keep = job.row["split"] == "test" and len(vn) <= MAX_VERTEX_MAP  # as solve_pair
            out[job.key] = write_pair(store, job, old, pair_result(part, res[k], vn, f) if keep else pair_result(part, res[k]), "done", "", seconds)
    return [out[job.key] for job in jobs]


def two_step(config: BuildConfig) -> bool:
    """Whether the pairs stage solves probe pairs first (:func:`probe_keys`): only where a group can
    settle on its plain map (``train.plain_below`` > 0 with residual networks)."""
    return config.train.plain_below > 0 and config.train.residual


def probe_keys(config: BuildConfig, jobs: list[PairJob]) -> set[tuple[str, int]]:
    """The pairs a two-step stage solves first: every test pair and, per group, the train shapes
    its training will hold out and as many probe shapes
    (:func:`proctex.store.samples.held_out_split`): enough to tell whether its plain map fits."""
    train = sorted({j.row["id"] for j in jobs if j.row["split"] == "train"})
    keys = {j.key for j in jobs if j.row["split"] != "train"}
    for g in sorted({j.group for j in jobs}):
        held, probes = held_out_split(train, config.seed, g, VAL_SHARE)
        keys.update((i, g) for i in held + probes)
    return keys


def settled_groups(store: FamilyStore, config: BuildConfig, jobs: list[PairJob], records: dict[tuple[str, int], dict[str, Any]], probes: set[tuple[str, int]]) -> dict[int, dict[str, float]]:
    """Groups whose probe pairs are all complete and whose plain map already fits their held-out
    shapes (:func:`proctex.build.groupdata.plain_groups` on what is solved: the train stage decides the
    same on the same pairs), with the plain maps' held-out errors. Writes ``pairs.parquet`` from
    ``records`` first: what the decision reads."""
    groups = sorted({j.group for j in jobs})
    ready = [g for g in groups if all(pair_complete(records.get(j.key)) for j in jobs if j.group == g and j.key in probes)]
    write_pairs_index(store, jobs, records)  # what group_training_data reads
    return {g: d["plain"] for g, d in plain_groups(store, config, ready).items()}


def skipped_record(job: PairJob, old: dict[str, Any] | None) -> dict[str, Any]:
    """The record of a train pair not solved because its group's plain map fits."""
    sid, g = job.key
    return {
        "id": sid,
        "split": job.row["split"],
        "group": g,
        "status": "skipped",
        "error": "",
        "part": -1,
        "residual": None,
        "chamfer": None,
        "converged": False,
        "iterations": 0,
        "seconds": 0.0,
        "attempts": (old or {}).get("attempts", 0),
        "path": "",
    }


def plan_pairs(store: FamilyStore, config: BuildConfig, log: Callable[[str], None] = print, splits: tuple[str, ...] = ("train", "test")) -> Plan:
    """The pairs stage: a cage pair for every (shape, non-degenerate template group) not complete
    yet, one batch per shape; ``pairs.parquet`` rewritten as they arrive. ``info["solved"]``: pairs run.

    In two steps where groups can settle on their plain map (:func:`two_step`): first the test
    pairs and each group's held-out and probe train pairs (:func:`probe_keys`); the plan's
    ``info["then"]`` plans the rest, where the train pairs of groups whose plain map already fits
    their held-out shapes are skipped (:func:`settled_groups`; the train stage would not train
    them). A build runs ``info["then"]`` after the plan (:func:`proctex.build.pipeline.build`)."""
    assets = load_assets(store)
    jobs = pair_jobs(store, config, assets, splits)
    records = pair_records(store, jobs)
    steps = two_step(config) and "train" in splits
    # a done stage is done with the groups it settled (a store keeps its config: they stay settled)
    settled = {int(g) for g in FamilyState.load(store).stage("pairs").get("settled", {})} if steps else set()
    if stage_done(store, "pairs") and all(pair_complete(records.get(j.key), settled) for j in jobs):
        return _done_plan()
    if not steps:
        return _pairs_plan(store, config, log, assets, jobs, records, {})  # skipped pairs solved too
    probes = probe_keys(config, jobs)
    first = [j for j in jobs if j.key in probes and not pair_complete(records.get(j.key))]
    if not first:
        return plan_rest(store, config, log, assets, jobs, records, probes)
    plan = _pairs_plan(store, config, log, assets, jobs, records, {}, only=first)
    plan.info["then"] = lambda: plan_rest(store, config, log, assets, jobs, pair_records(store, jobs), probes)
    return plan


def _done_plan() -> Plan:
    return Plan("pairs", [], run_pair_batch, finish=lambda results: None, skip="done already", info={"solved": 0})


def plan_rest(store: FamilyStore, config: BuildConfig, log: Callable[[str], None], assets, jobs: list[PairJob], records: dict[tuple[str, int], dict[str, Any]], probes: set[tuple[str, int]]) -> Plan:
    """The second step of a two-step pairs stage (:func:`plan_pairs`): the train pairs of settled
    groups recorded as skipped, every other pair not complete planned (a skipped pair of a group
    that no longer settles among them)."""
    settled = settled_groups(store, config, jobs, records, probes)
    skipped: dict[int, int] = {}
    for job in jobs:
        if job.group in settled and job.key not in probes and job.row["split"] == "train" and not pair_complete(records.get(job.key), settled):
            records[job.key] = skipped_record(job, records.get(job.key))
            store.write_json(StoreLayout.pair_record(*job.key), records[job.key])
            skipped[job.group] = skipped.get(job.group, 0) + 1
    for g, n in skipped.items():
        log(f"pairs: group {g}: its plain map fits its held-out shapes ({', '.join(f'{k} {v:.5f}' for k, v in settled[g].items())}): {n} train pairs skipped")
    return _pairs_plan(store, config, log, assets, jobs, records, settled)


def _pairs_plan(
    store: FamilyStore,
    config: BuildConfig,
    log: Callable[[str], None],
    assets,
    jobs: list[PairJob],
    records: dict[tuple[str, int], dict[str, Any]],
    settled: dict[int, dict[str, float]],
    only: list[PairJob] | None = None,
) -> Plan:
    """The plan solving ``only`` (default: every job not complete with groups ``settled``), one
    batch per shape (per :func:`pair_batch_size` shapes); its finish returns the stage's record once every job is complete (a first
    step's finish leaves the index to the next step, :func:`settled_groups`)."""
    todo = only if only is not None else [j for j in jobs if not pair_complete(records.get(j.key), settled)]
    by_shape: dict[str, list[PairJob]] = {}
    for job in todo:
        by_shape.setdefault(job.row["id"], []).append(job)
    per = pair_batch_size(config)
    shaped = list(by_shape.values())
    batches = [[j for b in shaped[k : k + per] for j in b] for k in range(0, len(shaped), per)]
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
        names = sorted({j.row["id"] for j in batch})
        log(f"pairs: {names[0] if len(names) == 1 else f'{names[0]} and {len(names) - 1} more'} ({clock['solved']}/{len(todo)} solved, {now - t0:.0f}s)")

    last: list[Plan] = []  # the plan whose finish this is (the last of three where pairs are solved here)

    def finish(results: list[list[dict[str, Any]]]) -> dict[str, Any] | None:
        last[-1].info.update(solved=len(todo), seconds=round(time.perf_counter() - t0, 2))
        return finish_pairs_stage(store, jobs, records, log, settled) if only is None else None

    # side by side in process from 16 pairs on (a pair takes about a second, a worker a few to start)
    if solves_here(config):
        return _prepare_plan(config, log, assets, shaped, collect, finish, last)
    plan = Plan("pairs", batches, run_pair_batch, finish, collect, context=assets, parallel=True, pool_min_jobs=16, threads=1)
    last.append(plan)
    return plan


@dataclass
class PreparedJob:
    """A pair prepared in a worker for the solve here (:func:`prepare_pair_batch`): its job, its
    old record, the shape's part (index, vertices, faces) and the prepared cage pair; ``seconds``:
    the preparation's time; ``result``: its solved cage, once solved."""

    job: PairJob
    old: dict[str, Any] | None
    part: int
    vertices: np.ndarray
    faces: np.ndarray
    pair: Any
    seconds: float
    result: Any = None


def prepare_pair_batch(store: FamilyStore, config: BuildConfig, jobs: list[PairJob], context: Any = None) -> list[Any]:
    """The CPU half of pairs solved here (:func:`solves_here`): each job's part found and its cage
    pair prepared (:func:`proctex.correspond.dense.prepare_cage_pair`), a :class:`PreparedJob`;
    a pair complete already, absent or failing is stored as :func:`run_pair_batch` stores it and
    its record returned instead."""
    from proctex.correspond.dense import prepare_cage_pair

    assets = context if context is not None else cached_assets(store, jobs[0].version if jobs else "")
    out: list[Any] = []
    shapes: dict[str, Shape | None] = {}
    for job in jobs:
        rel = StoreLayout.pair_record(*job.key)
        old = store.read_json(rel) if store.exists(rel) else None
        if pair_complete(old):
            out.append(old)
            continue
        t = time.perf_counter()
        try:
            if job.row["id"] not in shapes:
                shapes[job.row["id"]] = load_sample(store, job.row, config)
            inp = pair_input(shapes[job.row["id"]], assets, job.group)
            if inp is None:
                out.append(write_pair(store, job, old, None, "absent", "", time.perf_counter() - t))
                continue
            ga = assets.groups[job.group]
            pair = prepare_cage_pair(inp[1], inp[2], ga.vertices, ga.faces, config.corr_points, pair_seed(config, job.index, job.group), config.cage)
        except (ValueError, RuntimeError) as exc:
            out.append(write_pair(store, job, old, None, "failed", str(exc), time.perf_counter() - t))
            continue
        out.append(PreparedJob(job, old, inp[0], inp[1], inp[2], pair, time.perf_counter() - t))
    return out


def finish_pair_batch(store: FamilyStore, config: BuildConfig, items: list[Any], context: Any = None) -> list[dict[str, Any]]:
    """The last half of pairs solved here: each solved :class:`PreparedJob` finished as
    :func:`proctex.correspond.dense.correspond_parts` finishes a pair (the sweep chart's map where
    it fits better) and stored; one whose solve failed solved alone (:func:`run_pair_job`); a
    record passes through."""
    from proctex.correspond.dense import finish_cage_pair

    out = []
    for item in items:
        if not isinstance(item, PreparedJob):
            out.append(item)
            continue
        if item.result is None:
            assets = context if context is not None else cached_assets(store, item.job.version)
            out.append(run_pair_job(store, config, assets, item.job))
            continue
        t = time.perf_counter()
        corr = finish_cage_pair(item.pair, config.cage, item.result, t)
        keep = item.job.row["split"] == "test" and len(item.vertices) <= MAX_VERTEX_MAP  # as solve_pair
        pair = pair_result(item.part, corr, item.vertices, item.faces) if keep else pair_result(item.part, corr)
        out.append(write_pair(store, item.job, item.old, pair, "done", "", item.seconds + time.perf_counter() - t))
    return out


def solve_here(prepared: list[PreparedJob], config: BuildConfig, log: Callable[[str], None] = print) -> None:
    """Every group's prepared pairs solved in one cage program (buckets of one lattice) on this
    process's device; each job's ``result`` set (None where its group's solve failed: those are
    solved alone when finished)."""
    from proctex.correspond.dense import solve_prepared
    from proctex.pools import torch_threads

    by_group: dict[int, list[PreparedJob]] = {}
    for item in prepared:
        by_group.setdefault(item.job.group, []).append(item)
    for g, items in by_group.items():
        t = time.perf_counter()
        try:
            with torch_threads(1):  # a worker's one thread: on a CPU, the same bits as a pool's batch
                results = solve_prepared([i.pair for i in items], config.cage)
        except (ValueError, RuntimeError) as exc:  # out of device memory, say: each pair alone
            log(f"pairs: group {g}: its {len(items)} pairs in one program failed ({exc}); solving them one by one")
            continue
        share = (time.perf_counter() - t) / len(items)
        for item, res in zip(items, results):
            item.result, item.seconds = res, item.seconds + share
        log(f"pairs: group {g}: {len(items)} pairs solved in one program ({time.perf_counter() - t:.1f}s)")


def _prepare_plan(config: BuildConfig, log: Callable[[str], None], assets, shaped: list[list[PairJob]], collect, finish, last: list[Plan]) -> Plan:
    """Pairs solved here (:func:`solves_here`) in three steps: the workers prepare them, one batch
    per shape (:func:`prepare_pair_batch`); this process solves every group's in one program
    (:func:`solve_here`); the workers finish and store them (:func:`finish_pair_batch`), whose plan
    collects and finishes as the one-step stage does and then runs what the stage planned next."""

    by_key = {j.key: j for b in shaped for j in b}  # the job of a record that passed through (done, absent, failed)

    def prepared(results: list[list[Any]]) -> None:
        items = [r for batch in results for r in batch if isinstance(r, PreparedJob)]
        solve_here(items, config, log)
        after = plan.info.pop("then", None)  # what the stage planned after this step (plan_rest)

        def finishing() -> Plan:
            nxt = Plan(
                "pairs",
                [r for r in results if r],
                finish_pair_batch,
                finish,
                lambda b, out: collect([x.job if isinstance(x, PreparedJob) else by_key[(x["id"], x["group"])] for x in b], out),
                context=assets,
                parallel=True,
                pool_min_jobs=16,
                threads=1,
            )
            if after is not None:
                nxt.info["then"] = after
            last.append(nxt)
            return nxt

        plan.info["then"] = finishing
        return None

    plan = Plan("pairs", shaped, prepare_pair_batch, prepared, context=assets, parallel=True, pool_min_jobs=16, threads=1)
    return plan
