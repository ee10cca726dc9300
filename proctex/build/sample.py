"""The ``sample`` stage: sample the procedural model (or read a folder of samples) into ``meshes/`` and
``samples.parquet``."""

from __future__ import annotations

import json
from typing import Any, Callable

import pyarrow as pa

from proctex.build.plan import Plan
from proctex.geometry.meshio import obj_text
from proctex.geometry.parts import segment
from proctex.sources.registry import SampleJob
from proctex.store.config import BuildConfig
from proctex.store.layout import FamilyStore, StoreLayout
from proctex.store.state import stage_done


def sample_jobs(config: BuildConfig) -> list[SampleJob]:
    """Every sample of the family (the folder's, or ``n_train + n_test`` drawn from the model with the
    family seed), in order (:meth:`proctex.sources.registry.ShapeSource.sample_jobs`)."""
    return config.shapes().sample_jobs(config.source, config.seed)


def run_sample_job(store: FamilyStore, config: BuildConfig, job: SampleJob) -> dict[str, Any]:
    """Make one sample, write its mesh and its record (the mesh first: a record means both are
    complete); returns the record, a row of ``samples.parquet``. Idempotent."""
    rel = StoreLayout.sample_record(job.id)
    if store.exists(rel):
        return store.read_json(rel)
    shape = config.shapes().shape(job)
    path = StoreLayout.mesh(job.id)
    store.write_bytes(path, obj_text(shape.vertices, shape.faces).encode())
    seg = segment(shape)
    row = {
        "id": job.id,
        "split": job.split,
        "params": json.dumps(job.params, sort_keys=True),
        "mesh": path,
        "vertices": shape.n_vertices,
        "faces": shape.n_faces,
        "parts": seg.n_parts,
        # the part names the source gives (a node tree's frames and groups), "" where none: for reading and painting only
        "names": json.dumps([p.label for p in seg.parts]) if shape.labels is not None else "",
    }
    store.write_json(rel, row)
    return row


def finish_sample_stage(store: FamilyStore, rows: list[dict[str, Any]], notes: list[str] | None = None, space: list[dict] | None = None) -> dict[str, Any]:
    """Write ``samples.parquet`` (rows in sample order); returns the stage's record (``notes``: what
    the source said of its inputs, e.g. those held at a file's values; ``space``: the procedural
    model's parameter space, :meth:`ParamSpace.to_list`, which readers take from the record instead
    of opening the model), which the pipeline writes."""
    store.write_table(StoreLayout.SAMPLES, pa.Table.from_pylist(rows))
    return {"samples": len(rows), "train": sum(r["split"] == "train" for r in rows), **({"notes": notes} if notes else {}), **({"space": space} if space is not None else {})}


def source_notes(config: BuildConfig) -> list[str]:
    """What the family's source says of its inputs and spec file: a ``.blend`` model's inputs held at
    the file's values and defaults clamped into their ranges, the spec's keys not understood."""
    notes = list(config.source.spec_notes)
    model = config.shapes().model
    plan = getattr(model, "plan", None)
    if plan is not None and hasattr(plan, "notes"):
        notes += plan.notes()
    return notes


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
    notes = source_notes(config)
    model = config.shapes().model
    space = model.space.to_list() if model is not None else None
    for note in notes:
        log(f"sample: {note}")

    def finish(results: list[list[dict[str, Any]]]) -> dict[str, Any]:
        rows = [row for out in results for row in out]
        log(f"sample: {len(rows)} shapes")
        return finish_sample_stage(store, rows, notes, space)

    return Plan("sample", [jobs[i : i + SAMPLE_BATCH] for i in range(0, len(jobs), SAMPLE_BATCH)], run_sample_batch, finish)
