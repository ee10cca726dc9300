"""A built-in model's family written as a real export would write it: GLB files split at UV seams.

``python tests/bench/seamsplit.py MODEL OUT [--n-train 24 --n-test 8 --seed 0]`` writes ``OUT/train``
and ``OUT/test``: per shape ``<i>.glb`` (+y up, as glTF wants: the model's +z turned to +y), its
parameters ``<i>.json`` and its truth ``<i>.truth.npz`` (:mod:`proctex.sources.truthfiles`: the
model's canonical coordinates and part labels per vertex of the file). The shapes are the built-in
family's at that seed and tessellation (the same sample jobs). Each file's vertices are split where
a box-projection UV map has a seam: a face belongs to the chart of its normal's dominant axis and
sign (six charts, Blender's "cube projection"), and a vertex is written once per chart of its faces,
with that chart's UVs. The seams cut every part into pieces by index: the load path must stitch
them (:func:`proctex.geometry.meshio.stitch_split_edges`) before parts are found. A folder of these
files is a folder family with canonical truth (issue 52's thin, seam-split family: ``fork.seams``
in :mod:`fidelity_baseline`).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

#: z-up (the models) to y-up (glTF): (x, y, z) -> (x, z, -y), a proper rotation.
Z_TO_Y = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def box_charts(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(m,) int64 chart per face: ``2 * axis + (component < 0)`` of its normal's largest component
    (0..5); a degenerate face's normal is zero and takes chart 0."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    axis = np.argmax(np.abs(n), axis=1)
    negative = n[np.arange(len(f)), axis] < 0
    return (2 * axis + negative).astype(np.int64)


def split_at_seams(faces: np.ndarray, chart: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """Faces over vertices split at chart borders: ``(faces (m, 3) int64, source (k,) int64)``, where
    ``source[j]`` is the original vertex of new vertex ``j``; a vertex used by faces of c charts
    becomes c vertices, one per chart (new vertices in order of (original vertex, chart))."""
    faces = np.asarray(faces, dtype=np.int64)
    chart = np.asarray(chart, dtype=np.int64)
    if chart.shape != (len(faces),):
        raise ValueError(f"chart must be ({len(faces)},), got {chart.shape}")
    n_charts = int(chart.max()) + 1 if len(chart) else 1
    key = faces * n_charts + chart[:, None]
    uniq, inverse = np.unique(key.reshape(-1), return_inverse=True)
    if len(faces) and (faces.min() < 0 or faces.max() >= n_vertices):
        raise ValueError(f"faces index vertices 0..{n_vertices - 1}")
    return inverse.reshape(-1, 3).astype(np.int64), (uniq // n_charts).astype(np.int64)


def box_uv(vertices: np.ndarray, vertex_chart: np.ndarray) -> np.ndarray:
    """(k, 2) UVs of a box projection: each vertex projected along its chart's axis onto the other
    two, scaled by the mesh's size into [0, 1]."""
    v = np.asarray(vertices, dtype=np.float64)
    lo, size = v.min(0), max(float(np.ptp(v, axis=0).max()), 1e-12)
    axis = np.asarray(vertex_chart) // 2
    others = np.array([[1, 2], [0, 2], [0, 1]])[axis]
    return (np.take_along_axis(v, others, axis=1) - lo[others]) / size


def export_shape(shape: Any, path: Path) -> dict[str, int]:
    """Write ``shape`` (a built-in model's: canonical coordinates and labels) as a seam-split GLB at
    ``path`` with its truth beside it; ``{"vertices", "file_vertices", "faces"}``."""
    import trimesh

    from proctex.sources.truthfiles import truth_path, write_truth

    chart = box_charts(shape.vertices, shape.faces)
    faces, source = split_at_seams(shape.faces, chart, shape.n_vertices)
    vchart = np.zeros(len(source), dtype=np.int64)
    vchart[faces.reshape(-1)] = np.repeat(chart, 3)
    uv = box_uv(shape.vertices[source], vchart)
    mesh = trimesh.Trimesh(shape.vertices[source] @ Z_TO_Y.T, faces, visual=trimesh.visual.TextureVisuals(uv=uv), process=False)
    path.write_bytes(mesh.export(file_type="glb"))
    write_truth(truth_path(path), shape.canonical[source], shape.labels[source], shape.label_names)
    return {"vertices": shape.n_vertices, "file_vertices": len(source), "faces": len(faces)}


def export_family(model: str, out: Path, n_train: int, n_test: int, seed: int, tessellation: str = "adaptive") -> dict[str, Any]:
    """The built-in family ``model`` (its sample jobs at ``seed``) written to ``out`` as seam-split
    files (module docstring); a summary ``{"shapes", "vertices", "file_vertices"}`` (written to
    ``out/export.json``: a folder with it is complete)."""
    from proctex.store.config import BuildConfig

    cfg = BuildConfig.from_dict({"model": model, "n_train": n_train, "n_test": n_test, "seed": seed, "tessellation": tessellation})
    shapes = cfg.shapes()
    counts = {"shapes": 0, "vertices": 0, "file_vertices": 0}
    for job in shapes.sample_jobs(cfg.source, cfg.seed):
        folder = out / job.split
        folder.mkdir(parents=True, exist_ok=True)
        name = f"{job.index}"
        c = export_shape(shapes.shape(job), folder / f"{name}.glb")
        (folder / f"{name}.json").write_text(json.dumps(job.params, sort_keys=True) + "\n")
        counts["shapes"] += 1
        counts["vertices"] += c["vertices"]
        counts["file_vertices"] += c["file_vertices"]
    summary = {"model": model, "seed": seed, "n_train": n_train, "n_test": n_test, "tessellation": tessellation, **counts}
    (out / "export.json").write_text(json.dumps(summary, indent=1) + "\n")
    return summary


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("model")
    ap.add_argument("out")
    ap.add_argument("--n-train", type=int, default=24)
    ap.add_argument("--n-test", type=int, default=8)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--tessellation", default="adaptive")
    args = ap.parse_args(argv)
    summary = export_family(args.model, Path(args.out), args.n_train, args.n_test, args.seed, args.tessellation)
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
