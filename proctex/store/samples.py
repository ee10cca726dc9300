"""The samples and pairs records of a family: ``samples.parquet`` rows, their meshes (or shapes
regenerated from their parameters) and the stored cage pairs."""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from proctex.geometry.meshio import load_mesh_bytes
from proctex.geometry.shape import Shape
from proctex.sources.registry import source_kind
from proctex.store.config import BuildConfig
from proctex.store.layout import FamilyStore, StoreLayout


def samples(store: FamilyStore) -> list[dict[str, Any]]:
    return store.read_table(StoreLayout.SAMPLES).to_pylist()


def read_mesh(store: FamilyStore, rel: str) -> Shape:
    shape, _ = load_mesh_bytes(store.read_bytes(rel), rel)
    return shape


def load_sample(store: FamilyStore, row: dict[str, Any], config: BuildConfig | None = None) -> Shape:
    """A sample as a :class:`Shape`. Model families regenerate it from its parameters (exact, with
    labels and canonical coordinates); folder families read the stored mesh."""
    params = json.loads(row["params"])
    if config is not None and source_kind(config.source).regenerates:
        shape = config.procedural_model().generate(params)
        shape.source = row["mesh"]
        return shape
    shape = read_mesh(store, row["mesh"])
    shape.params = params
    return shape


def pair_seed(config: BuildConfig, index: int, group: int) -> int:
    """The seed of pair (sample ``index``, ``group``): a function of the family seed and the pair only,
    so any process, in any order, solves a pair the same way."""
    return config.seed * 1_000_003 + index * 97 + group


def read_pair(store: FamilyStore, sid: str, group: int, faces: bool = False):
    """(src (n, 3), dst (n, 3)) float32 of a stored pair; with ``faces``, also the (n,) template
    face of each target."""
    t = store.read_table(StoreLayout.pair(sid, group))
    src = np.stack([t.column(k).to_numpy() for k in ("sx", "sy", "sz")], axis=1)
    dst = np.stack([t.column(k).to_numpy() for k in ("tx", "ty", "tz")], axis=1)
    return (src, dst, t.column("face").to_numpy()) if faces else (src, dst)
