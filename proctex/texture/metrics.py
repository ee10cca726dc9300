"""Texture measures (docs/results.md): coverage (:func:`coverage`, visible pixels that read an unpainted
texel) and view similarity (:func:`view_similarity`: SSIM, PSNR and optionally LPIPS between renders).
The ground-truth correspondence error is :mod:`proctex.correspond.metrics`'s.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


# ---------------------------------------------------------------------------------------- coverage
@dataclass
class Coverage:
    """Coverage of a textured shape (docs/results.md): ``share`` of visible pixels that read an unpainted
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
    views: list | None = None,
) -> Coverage:
    """Share of visible surface pixels (six canonical views) landing on unpainted texels.

    Args:
        vertices (n, 3), faces (m, 3), corner_uv (m, 3, 2), face_group (m,) int64: the textured mesh.
        painted: per group an (H, W) bool mask of texels holding colour.
        up: the shape's up axis; size: view size.
        views: the six views of this mesh traced already
            (:func:`proctex.texture.render.canonical_buffers` at ``size``): every UV layout of one
            mesh is measured on one tracing.
    """
    from .render import Tracer, check_views, canonical_buffers, pixel_uv, with_labels
    from .uv import bilinear_texels

    fg = np.asarray(face_group, dtype=np.int64)
    if fg.shape != (len(faces),):
        raise ValueError(f"face_group must be ({len(faces)},), got {fg.shape}")
    if views is None:
        views = canonical_buffers(vertices, faces, up, size, Tracer(vertices, faces, backend))
    bad = total = 0
    for view in check_views(views, len(faces), size):
        b = with_labels(view, face_group=fg)
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
    return Coverage(bad / total if total else 0.0, bad, total, len(views))


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
    :class:`proctex.texture.lpips.LPIPS`) is given. Identical sets give SSIM 1, PSNR :data:`PSNR_CAP`, LPIPS 0.
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
