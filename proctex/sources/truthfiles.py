"""Ground truth that travels beside a folder family's mesh files, for measuring only.

A mesh file ``<stem>.<ext>`` of a folder family may have a sidecar ``<stem>.truth.npz`` holding, per
vertex *of the file* (its own order, before any stitching or welding on load):

- ``canonical`` (n, 3) float: the vertex's canonical coordinates (the same point of the same part
  has the same coordinates on every shape of the family: a generator's own frame);
- ``labels`` (n,) int: the index of its part's name in ``label_names``;
- ``label_names`` (k,) str: the parts' semantic names.

The build never reads these files (sample, template, pairs and training see the meshes only); the
evaluation does, as the ``canonical`` truth of the folder family (:func:`attach_file_truth`, which
carries the arrays through the load's stitching to the stored shape's vertices). A family exported
by its own generator with these sidecars is measured on truth as a built-in model is, however its
files split vertices at UV seams.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import numpy as np

from proctex.geometry.shape import Shape

SUFFIX = ".truth.npz"
#: The most part names a sidecar may give, and the longest name: bounds on a damaged or hostile file.
MAX_LABELS = 4096
MAX_NAME = 200


def truth_path(mesh_path: str | os.PathLike) -> Path:
    """The sidecar of ``mesh_path``: ``<stem>.truth.npz`` beside it."""
    p = Path(mesh_path)
    return p.with_name(p.stem + SUFFIX)


def write_truth(path: str | os.PathLike, canonical: np.ndarray, labels: np.ndarray, label_names: Sequence[str]) -> None:
    """Write a sidecar (validated as :func:`read_truth` reads it).

    Args:
        canonical: (n, 3) float, finite; labels: (n,) int in ``[0, len(label_names))``.
    """
    canonical = np.asarray(canonical, dtype=np.float64)
    labels = np.asarray(labels)
    _check(canonical, labels, [str(n) for n in label_names], len(canonical), str(path))
    with open(path, "wb") as fh:
        np.savez_compressed(fh, canonical=canonical, labels=labels.astype(np.int32), label_names=np.array([str(n) for n in label_names]))


def _check(canonical: np.ndarray, labels: np.ndarray, names: list[str], n: int, where: str) -> None:
    if canonical.shape != (n, 3):
        raise ValueError(f"{where}: canonical must be ({n}, 3) (one row per vertex of the mesh file), got {canonical.shape}")
    if not np.isfinite(canonical).all():
        raise ValueError(f"{where}: canonical has NaN or infinite values")
    if labels.shape != (n,) or not np.issubdtype(labels.dtype, np.integer):
        raise ValueError(f"{where}: labels must be ({n},) integers, got {labels.shape} {labels.dtype}")
    if not 0 < len(names) <= MAX_LABELS or any(not name or len(name) > MAX_NAME for name in names):
        raise ValueError(f"{where}: label_names must be 1..{MAX_LABELS} names of 1..{MAX_NAME} characters")
    if n and (labels.min() < 0 or labels.max() >= len(names)):
        raise ValueError(f"{where}: labels must index label_names (0..{len(names) - 1}), got {labels.min()}..{labels.max()}")


def read_truth(path: str | os.PathLike, n_vertices: int) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """A sidecar's ``(canonical (n, 3) float64, labels (n,) int32, label_names)`` for a mesh file of
    ``n_vertices`` vertices; ``ValueError`` naming the file for a missing, damaged or mismatched one."""
    where = str(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            canonical = np.asarray(data["canonical"], dtype=np.float64)
            labels = np.asarray(data["labels"])
            names = [str(n) for n in np.asarray(data["label_names"]).reshape(-1)[: MAX_LABELS + 1]]
    except FileNotFoundError:
        raise ValueError(f"{where}: no truth file") from None
    except (OSError, ValueError, KeyError, EOFError) as exc:
        raise ValueError(f"{where}: not a readable truth file (canonical, labels, label_names): {exc}") from None
    _check(canonical, labels, names, n_vertices, where)
    return canonical, labels.astype(np.int32), tuple(names)


def attach_file_truth(shape: Shape, mesh_path: str | os.PathLike, tol: float = 1e-6) -> Shape:
    """``shape`` (a folder sample as the build stored it: ``mesh_path`` loaded, stitched and welded)
    with the canonical coordinates and labels of ``mesh_path``'s sidecar on its vertices.

    The file is loaded again as the sample stage loaded it (:func:`proctex.geometry.meshio.load_mesh`),
    whose report maps each file vertex to a stored vertex; a stored vertex takes its first file
    vertex's truth (vertices welded together lie at one point). Raises ``ValueError`` where the
    stored shape is not what the file loads to (a changed file: positions further apart than
    ``tol`` times the shape's size) or a stored vertex has no file vertex.
    """
    from proctex.geometry.meshio import load_mesh

    loaded, report = load_mesh(mesh_path)
    if loaded.n_vertices != shape.n_vertices:
        raise ValueError(f"{mesh_path}: loads to {loaded.n_vertices} vertices, the stored sample has {shape.n_vertices}: the file changed since the build")
    size = float(np.ptp(loaded.vertices, axis=0).max()) if loaded.n_vertices else 1.0
    if loaded.n_vertices and np.abs(loaded.vertices - shape.vertices).max() > tol * max(size, 1e-12):
        raise ValueError(f"{mesh_path}: its vertices are not the stored sample's: the file changed since the build")
    vmap = np.asarray(report.vertex_map, dtype=np.int64)
    canonical, labels, names = read_truth(truth_path(mesh_path), len(vmap))
    valid = np.flatnonzero(vmap >= 0)
    stored, first = np.unique(vmap[valid], return_index=True)  # each stored vertex's first file vertex
    can = np.full((shape.n_vertices, 3), np.nan)
    lab = np.full(shape.n_vertices, -1, dtype=np.int64)
    can[stored] = canonical[valid[first]]
    lab[stored] = labels[valid[first]]
    if (lab < 0).any():
        raise ValueError(f"{mesh_path}: {int((lab < 0).sum())} stored vertices have no vertex in the file")
    return Shape(
        shape.vertices, shape.faces, canonical=can, labels=lab.astype(np.int32), label_names=names, params=shape.params, source=shape.source, corner_uv=shape.corner_uv, face_source=shape.face_source
    )


def folder_truth(folder: str | os.PathLike) -> bool:
    """Whether every mesh file of the folder family at ``folder`` has a sidecar (the family then has
    canonical truth); False for a folder that cannot be read."""
    from proctex.sources.files import FolderSource

    try:
        src = FolderSource(folder)
    except (ValueError, OSError):
        return False
    return all(truth_path(s.mesh_path).is_file() for s in src.samples)


def sample_mesh_paths(folder: str | os.PathLike) -> dict[str, str]:
    """``{sample id as a family stores it (train_3 for train/3): its mesh file}`` of the folder family
    at ``folder``."""
    from proctex.sources.files import FolderSource

    return {s.store_id: s.mesh_path for s in FolderSource(folder).samples}
