"""The ``pairs`` stage: the cage correspondence of every (train or test shape, template group)."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
import pyarrow as pa

from proctex.build.plan import Plan, run_in_process
from proctex.geometry.parts import part_mesh, segment
from proctex.geometry.shape import Shape
from proctex.store.config import BuildConfig
from proctex.store.layout import FamilyStore, StoreLayout
from proctex.store.samples import load_sample, pair_seed, part_digest, samples, write_pair_vertices
from proctex.store.state import FamilyState, build_stamp, mark_stage, stage_done
from proctex.transfer.assets import load_assets


def pair_input(shape: Shape, assets, group: int) -> tuple[int, np.ndarray, np.ndarray] | None:
    """The part of ``shape`` that maps onto template ``group``: ``(part index, vertices (j, 3),
    faces (k, 3))`` (mirrored members kept wound outward), or None when the shape lacks the group."""
    from proctex.transfer.assign import assign_parts, choose_part, representative_part

    seg = segment(shape)
    a = choose_part(assign_parts(shape, seg, assets), group)
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
    from proctex.correspond.dense import deform

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
    from proctex.correspond.dense import correspond_parts

    inp = pair_input(shape, assets, group)
    if inp is None:
        return None
    part, vn, f = inp
    ga = assets.groups[group]
    res = correspond_parts(vn, f, ga.vertices, ga.faces, method="cage", n_points=config.corr_points, seed=seed, cage=config.cage)
    return pair_result(part, res, vn, f) if vertex_map and len(vn) <= MAX_VERTEX_MAP else pair_result(part, res)


@dataclass
class PairJob:
    """One cage correspondence to solve: sample ``index`` (its ``samples.parquet`` row) and template ``group``."""

    index: int
    row: dict[str, Any]
    group: int

    @property
    def key(self) -> tuple[str, int]:
        return (self.row["id"], self.group)


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
        # a test pair keeps where it sends its part's vertices: the evaluation's cage tracker reads them
        pair = solve_pair(shape, assets, g, config, pair_seed(config, job.index, g), vertex_map=job.row["split"] == "test")
        status = "done" if pair is not None else "absent"
        error = ""
    except (ValueError, RuntimeError) as exc:
        pair, status, error = None, "failed", str(exc)
    if pair is not None and pair["mapped"] is not None:
        write_pair_vertices(store, sid, g, **pair["mapped"])
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
        mark_stage(store, "pairs", pairs=len(records))


INDEX_EVERY = 5.0  # seconds between rewrites of pairs.parquet while pairs arrive


# Template assets per (store, build stamp), kept between batches by a process that runs pair batches
# without them (a Ray worker).
_ASSETS: dict[tuple[str, str], Any] = {}


def cached_assets(store: FamilyStore) -> Any:
    """The store's template assets, loaded once per process and family version (:func:`build_stamp`)."""
    state = FamilyState.load(store)
    key = (store.uri, build_stamp(store, state))
    if key not in _ASSETS:
        _ASSETS.clear()
        _ASSETS[key] = load_assets(store, state)
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

    # side by side in process from 16 pairs on (a pair takes about a second, a worker a few to start)
    plan = Plan("pairs", list(by_shape.values()), run_pair_batch, finish, collect, context=assets, parallel=True, pool_min_jobs=16)
    return plan


def stage_pairs(store: FamilyStore, config: BuildConfig, log: Callable[[str], None] = print, splits: tuple[str, ...] = ("train", "test")) -> None:
    """Cage pairs for every (shape, non-degenerate template group); skips pairs already complete
    (:func:`plan_pairs`, here)."""
    run_in_process(plan_pairs(store, config, log, splits), store, config, log)
