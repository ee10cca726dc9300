"""Evaluation measures (DESIGN §6).

Ground-truth correspondence error: built-in models give every vertex canonical coordinates that
mean the same surface point for every parameter setting. A source sample's canonical coordinates
(interpolated barycentrically) are looked up on the template part's *canonical mesh* (the same
faces over the canonical coordinates), which gives the true template point; the error is its
distance to the predicted template point in the template part's normalised frame (divided by the
part's L∞ radius). The orientation check counts points whose predicted template face normal
points against the true one (an inside mapped onto an outside).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from proctex.geometry.surface import SurfaceIndex, face_normals, normalised_frame


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


def interpolate(values: np.ndarray, faces: np.ndarray, face_index: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """Barycentric interpolation of per-vertex ``values (n, d)`` at ``(face_index (k,), bary (k, 3))``."""
    return np.einsum("kj,kjd->kd", bary, values[faces[face_index]])


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


# ---------------------------------------------------------------------------------------- coverage
@dataclass
class Coverage:
    """Coverage of a textured shape (DESIGN §6): ``share`` of visible pixels that read an unpainted
    texel (any of the four a bilinear lookup touches), out of ``pixels`` visible pixels in ``views``."""

    share: float
    unpainted_pixels: int
    pixels: int
    views: int

    def to_dict(self) -> dict[str, Any]:
        return {"share": self.share, "unpainted_pixels": self.unpainted_pixels, "pixels": self.pixels, "views": self.views}


def coverage(
    vertices: np.ndarray,
    faces: np.ndarray,
    corner_uv: np.ndarray,
    face_group: np.ndarray,
    painted: list[np.ndarray],
    up: str = "z",
    size: int = 512,
    backend: str = "auto",
) -> Coverage:
    """Share of visible surface pixels (six canonical views) landing on unpainted texels.

    Args:
        vertices (n, 3), faces (m, 3), corner_uv (m, 3, 2), face_group (m,) int64: the textured mesh.
        painted: per group an (H, W) bool mask of texels holding colour.
        up: the shape's up axis; size: view size.
    """
    from .render import Tracer, bounding_sphere, canonical_cameras, pixel_uv, render_buffers
    from .uv import bilinear_texels

    fg = np.asarray(face_group, dtype=np.int64)
    tracer = Tracer(vertices, faces, backend)
    c, r = bounding_sphere(vertices)
    bad = total = 0
    cams = canonical_cameras(c, r, up, size)
    for cam in cams:
        b = render_buffers(tracer, cam, face_group=fg)
        m = b.mask
        g = b.group[m]
        uv = pixel_uv(b, corner_uv)[m]
        total += int(m.sum())
        bad += int((g < 0).sum())  # faces without any texture count as unpainted
        for gi, mask in enumerate(painted):
            sel = g == gi
            if sel.any():
                idx = bilinear_texels(uv[sel], mask.shape[0], mask.shape[1])
                bad += int((~mask.ravel()[idx]).any(axis=1).sum())
    return Coverage(bad / total if total else 0.0, bad, total, len(cams))


# ------------------------------------------------------------------------------------ view similarity
#: PSNR of identical images is infinite; reported values are capped here (dB) so JSON stays finite.
PSNR_CAP = 100.0


@dataclass
class ViewSimilarity:
    """Similarity of two sets of renders from the same views: ``ssim`` and ``psnr`` (dB, capped at
    :data:`PSNR_CAP`) averaged over views, ``lpips`` (None without a model), and per view."""

    ssim: float
    psnr: float
    lpips: float | None
    per_view: list[dict[str, float]]

    def to_dict(self) -> dict[str, Any]:
        return {"ssim": self.ssim, "psnr": self.psnr, "lpips": self.lpips, "per_view": self.per_view}


def view_similarity(reference: list[np.ndarray], images: list[np.ndarray], lpips: Any = None) -> ViewSimilarity:
    """SSIM and PSNR (scikit-image; RGB, data range 255) between ``reference[k]`` and ``images[k]``,
    each (H, W, 3) uint8 of the same view, averaged over views; LPIPS too when ``lpips`` (a
    :class:`proctex.lpips.LPIPS`) is given. Identical sets give SSIM 1, PSNR :data:`PSNR_CAP`, LPIPS 0.
    """
    from skimage.metrics import peak_signal_noise_ratio, structural_similarity

    if len(reference) != len(images) or not images:
        raise ValueError(f"need equally many (>= 1) reference and compared views, got {len(reference)} and {len(images)}")
    per_view = []
    for a, b in zip(reference, images):
        a, b = np.asarray(a), np.asarray(b)
        if a.shape != b.shape or a.ndim != 3 or a.shape[2] != 3 or a.dtype != np.uint8 or b.dtype != np.uint8:
            raise ValueError(f"views must be equally sized (H, W, 3) uint8 images, got {a.shape} {a.dtype} and {b.shape} {b.dtype}")
        ssim = float(structural_similarity(a, b, channel_axis=2, data_range=255))
        psnr = PSNR_CAP if np.array_equal(a, b) else min(PSNR_CAP, float(peak_signal_noise_ratio(a, b, data_range=255)))
        view = {"ssim": ssim, "psnr": psnr}
        if lpips is not None:
            view["lpips"] = float(lpips.distance(a, b))
        per_view.append(view)
    mean = lambda k: float(np.mean([v[k] for v in per_view]))  # noqa: E731
    return ViewSimilarity(mean("ssim"), mean("psnr"), mean("lpips") if lpips is not None else None, per_view)
