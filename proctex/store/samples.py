"""The samples and pairs records of a family: ``samples.parquet`` rows, their meshes (or shapes
regenerated from their parameters) and the stored cage pairs."""

from __future__ import annotations

import hashlib
import json
from typing import Any

import numpy as np

from proctex.geometry.meshio import load_mesh_bytes
from proctex.geometry.shape import Shape
from proctex.sources.registry import source_kind
from proctex.store.config import BuildConfig
from proctex.store.layout import FamilyStore, StoreDamaged, StoreLayout, check_digest, encode_arrays


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


#: The arrays of a shape record besides ``vertices`` and ``faces``, each stored when the shape has it.
_SHAPE_OPTIONAL = ("canonical", "labels", "corner_uv", "face_source")


def shape_record(shape: Shape) -> bytes:
    """A :class:`Shape` whole as ``.npz`` bytes: its arrays, and its label names, parameters and
    source as UTF-8 JSON in a ``meta`` byte array (numeric arrays only: reading never unpickles).
    :func:`read_shape_record` gives back an equal shape (``derived`` starts empty)."""
    meta = {"label_names": list(shape.label_names), "params": shape.params, "source": shape.source}
    arrays = {"vertices": shape.vertices, "faces": shape.faces, "meta": np.frombuffer(json.dumps(meta, sort_keys=True).encode(), dtype=np.uint8)}
    arrays.update({k: getattr(shape, k) for k in _SHAPE_OPTIONAL if getattr(shape, k) is not None})
    return encode_arrays(**arrays)


def read_shape_record(store: FamilyStore, rel: str, expected: str | None = None) -> Shape:
    """The shape stored at ``rel`` by :func:`shape_record`; ``expected``: its recorded sha256 digest
    (checked when given). A file that is not such a record is :class:`StoreDamaged`, naming it."""
    data = store.read_bytes(rel)
    check_digest(data, expected, f"{store.uri}: {rel}")
    arrays = store.read_arrays_of(data, rel)
    try:
        meta = json.loads(arrays.pop("meta").tobytes().decode())
        return Shape(
            arrays.pop("vertices"),
            arrays.pop("faces"),
            label_names=tuple(meta["label_names"]),
            params=dict(meta["params"]),
            source=str(meta["source"]),
            **{k: arrays[k] for k in _SHAPE_OPTIONAL if k in arrays},
        )
    except (KeyError, TypeError, ValueError, UnicodeDecodeError) as exc:
        raise StoreDamaged(f"{store.uri}: {rel} is not a shape record ({type(exc).__name__}: {str(exc)[:200]})") from exc


def pair_seed(config: BuildConfig, index: int, group: int) -> int:
    """The seed of pair (sample ``index``, ``group``): a function of the family seed and the pair only,
    so any process, in any order, solves a pair the same way."""
    return config.seed * 1_000_003 + index * 97 + group


def held_out_split(ids: list[str], seed: int, group: int, share: float) -> tuple[list[str], list[str]]:
    """A group's held-out train shapes and as many probe shapes (sorted lists of ids) out of its
    train shapes ``ids``: ``max(1, round(share * n))`` held out (none below three shapes), drawn by
    the family ``seed`` and the ``group``; the probes are drawn from the rest after them. Depends
    on ``ids`` only (not on which pairs are solved), so the pairs stage can solve these first and
    the train stage holds the same shapes out (:func:`proctex.build.groupdata.group_training_data`)."""
    ids = sorted(ids)
    rng = np.random.default_rng(seed + group)
    n = max(1, int(round(share * len(ids)))) if len(ids) > 2 else 0
    if not n:
        return [], []
    held = set(rng.choice(ids, size=n, replace=False).tolist())
    rest = [i for i in ids if i not in held]
    return sorted(held), sorted(rng.permutation(rest)[:n].tolist()) if rest else []


def held_out_ids(train_ids: list[str], solved: list[str], seed: int, group: int, share: float) -> list[str]:
    """The shapes a group holds out (sorted ids) among its ``solved`` train shapes: the family's
    draw over all its ``train_ids`` (:func:`held_out_split`) where the group was solved; the
    group's own draw over ``solved`` where that holds none out or leaves none to train on (a
    group in few shapes; that draw holds none out below three shapes)."""
    have = set(solved)
    held = [i for i in held_out_split(train_ids, seed, group, share)[0] if i in have]
    if not held or len(held) >= len(have):
        held = held_out_split(sorted(have), seed, group, share)[0]
    return held


def part_digest(vertices: np.ndarray, faces: np.ndarray) -> str:
    """A short digest of a part mesh (float64 vertices, int64 faces): what a stored vertex map was
    made for (a map of another part, or of this part computed on another machine, is not reused)."""
    h = hashlib.sha256(np.ascontiguousarray(vertices, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(faces, dtype=np.int64).tobytes())
    return h.hexdigest()[:32]


def write_pair_vertices(store: FamilyStore, sid: str, group: int, vertices: np.ndarray, digest: str) -> None:
    """Store where a pair's correspondence sends its source part's vertices (``vertices (j, 3)``,
    float64, the template's normalised frame) for the part of :func:`part_digest` ``digest``."""
    store.write_arrays(StoreLayout.pair_vertices(sid, group), vertices=np.asarray(vertices, dtype=np.float64), digest=np.frombuffer(digest.encode("ascii"), dtype=np.uint8))


def read_pair_vertices(store: FamilyStore, sid: str, group: int, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray | None:
    """The stored map of the part ``(vertices (j, 3), faces)`` of pair ``(sid, group)``
    (:func:`write_pair_vertices`): (j, 3) float64, or None when none is stored, it was made for
    another part, or its file is damaged (the caller solves the pair instead)."""
    rel = StoreLayout.pair_vertices(sid, group)
    if not store.exists(rel):
        return None
    try:
        arrays = store.read_arrays(rel)
    except ValueError:
        return None
    mapped, digest = arrays.get("vertices"), arrays.get("digest")
    if mapped is None or digest is None or mapped.shape != np.shape(vertices) or not np.isfinite(mapped).all():
        return None
    if digest.dtype != np.uint8 or digest.tobytes() != part_digest(vertices, faces).encode("ascii"):
        return None
    return mapped.astype(np.float64)


def read_pair(store: FamilyStore, sid: str, group: int, faces: bool = False):
    """(src (n, 3), dst (n, 3)) float32 of a stored pair; with ``faces``, also the (n,) template
    face of each target."""
    t = store.read_table(StoreLayout.pair(sid, group))
    src = np.stack([t.column(k).to_numpy() for k in ("sx", "sy", "sz")], axis=1)
    dst = np.stack([t.column(k).to_numpy() for k in ("tx", "ty", "tz")], axis=1)
    return (src, dst, t.column("face").to_numpy()) if faces else (src, dst)
