"""The ``template`` stage: the train sample with the most kinds of part, nearest the mean parameters,
recorded whole (``template/shape.npz``, with its labels and part names) so that no reader makes it again."""

from __future__ import annotations

import json
from typing import Any, Callable

import numpy as np

from proctex.store.config import BuildConfig
from proctex.store.layout import FamilyStore, StoreLayout, digest
from proctex.store.samples import load_sample, read_mesh, samples, shape_record
from proctex.store.state import stage_done


def template_step(store: FamilyStore, config: BuildConfig, log: Callable[[str], None] = print) -> dict[str, Any] | None:
    """Pick the template among the train samples: of those with the most kinds of part
    (:func:`proctex.geometry.parts.part_kinds`, so a family with optional parts gets a template
    that carries them), the one nearest the mean parameters. Returns the stage's record (None: done
    already)."""
    if stage_done(store, "template"):
        log("template: done already")
        return None
    from proctex.geometry.parts import part_kinds
    from proctex.params import infer_space, select_template

    rows = [r for r in samples(store) if r["split"] == "train"]
    params = [json.loads(r["params"]) for r in rows]
    model = config.shapes().model
    space = model.space if model is not None else infer_space(params)
    kinds = [part_kinds(read_mesh(store, r["mesh"])) for r in rows]
    i = select_template(space, params, coverage=kinds) if len(space) else int(np.argmax(kinds))
    nearest = select_template(space, params) if len(space) else 0
    shape = load_sample(store, rows[i], config)  # model families: made again from its parameters, labels included
    shape.source = StoreLayout.TEMPLATE_MESH
    record = shape_record(shape)  # what readers load: never made again (no reader starts Blender)
    store.write_all([(StoreLayout.TEMPLATE_MESH, store.read_bytes(rows[i]["mesh"])), (StoreLayout.TEMPLATE_SHAPE, record)])
    why = "" if i == nearest else f"; the sample nearest the mean ({rows[nearest]['id']}) has {kinds[nearest]}"
    log(f"template: {rows[i]['id']} ({kinds[i]} kinds of part, the most of the {len(rows)} train samples{why})")
    return {"id": rows[i]["id"], "params": params[i], "part_kinds": kinds[i], "shape": digest(record)}
