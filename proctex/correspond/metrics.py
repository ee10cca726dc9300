"""Ground-truth correspondence error (:func:`gt_correspondence_error`), for measuring only: nothing is
fitted or selected on it.

Built-in models give every vertex canonical coordinates that mean the same surface point for every
parameter setting. A source sample's canonical coordinates (interpolated barycentrically) are looked
up on the template part's *canonical mesh* (the same faces over the canonical coordinates), which
gives the true template point; the error is its distance to the predicted template point in the
template part's normalised frame (divided by the part's L∞ radius). The orientation check counts
points whose predicted template face normal points against the true one (an inside mapped onto an
outside).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from proctex.geometry.surface import SurfaceIndex, face_normals, interpolate, normalised_frame


@dataclass
class GTError:
    """Ground-truth error of a correspondence: ``mean``, ``p95``, ``max`` (normalised template
    frame), ``flipped`` (share of points whose mapped normal opposes the true one), ``n`` points."""

    mean: float
    p95: float
    max: float
    flipped: float
    n: int

    def to_dict(self) -> dict[str, Any]:
        return {"mean": self.mean, "p95": self.p95, "max": self.max, "flipped": self.flipped, "n": self.n}


def canonical_lookup(vertices: np.ndarray, faces: np.ndarray, canonical: np.ndarray, query: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Surface points of a part whose canonical coordinates are nearest to ``query (k, 3)``.

    Returns ``(points (k, 3), faces (k,), bary (k, 3))`` on the part mesh ``(vertices, faces)``.
    """
    hit = SurfaceIndex(canonical, faces).query(query)
    return interpolate(vertices, faces, hit.faces, hit.bary), hit.faces, hit.bary


def gt_correspondence_error(
    source_canonical: np.ndarray,
    predicted_points: np.ndarray,
    predicted_faces: np.ndarray,
    template_vertices: np.ndarray,
    template_faces: np.ndarray,
    template_canonical: np.ndarray,
) -> GTError:
    """Ground-truth error of predicted template points.

    Args:
        source_canonical: (k, 3) canonical coordinates of the source samples.
        predicted_points: (k, 3) predicted template points (world); predicted_faces: (k,) their faces.
        template_vertices, template_faces, template_canonical: the template part mesh and its
            per-vertex canonical coordinates.
    """
    src = np.asarray(source_canonical, dtype=float)
    pred = np.asarray(predicted_points, dtype=float)
    if src.shape != pred.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) == 0:
        raise ValueError(f"need matching non-empty (k, 3) canonical and predicted points, got {src.shape} and {pred.shape}")
    true_pts, true_faces, _ = canonical_lookup(template_vertices, template_faces, template_canonical, src)
    _, radius = normalised_frame(template_vertices[np.unique(template_faces)])
    err = np.linalg.norm(pred - true_pts, axis=1) / max(radius, 1e-300)
    fn = face_normals(template_vertices, template_faces)
    flipped = float(np.mean(np.einsum("kd,kd->k", fn[np.asarray(predicted_faces)], fn[true_faces]) < 0))
    return GTError(float(err.mean()), float(np.percentile(err, 95)), float(err.max()), flipped, len(err))
