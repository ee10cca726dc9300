"""What painters see and return: the view-painter interface of the multi-view paint loop (docs/texturing.md).

A *view painter* is asked, for one camera, to paint the rendered view of the template. It receives the
current render of the texture, a trimap saying which pixels must be generated, refined or kept, and the
geometry buffers (depth, normals, 3D points, group ids). It returns an RGB image of the same size; the
loop back-projects only the pixels it asked for into the group textures.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

# Trimap values (``ViewRequest.trimap``).
BACKGROUND = 0  # no surface under the pixel
KEEP = 1  # already painted from a better angle: leave as rendered
REFINE = 2  # painted, but this view sees it better: may be repainted, staying close to the render
GENERATE = 3  # never painted: paint freely


@dataclass
class ViewRequest:
    """One view to paint. Image arrays are (H, W, ...) with row 0 at the top.

    Attributes:
        prompt: the global prompt.
        group_prompts: prompt per group id (already resolved: every group in the view has one).
        rgb: (H, W, 3) float32 in [0, 1], the current texture rendered from this camera (unpainted texels
            and background are ``fill``-coloured).
        trimap: (H, W) uint8 of BACKGROUND / KEEP / REFINE / GENERATE.
        depth: (H, W) float32 distance along the ray, ``inf`` on background.
        normal: (H, W, 3) float32 unit world-space normals facing the camera, 0 on background.
        points: (H, W, 3) float32 world-space surface points, 0 on background.
        group: (H, W) int64 part-group id per pixel, -1 on background.
        center: (3,) float64 and ``scale`` float: the shape's normalised frame
            (``(points - center) / scale`` lies in [-1, 1]^3), so painters can work in shape units.
        view_index: index of this view in the camera path; n_views: length of the path.
        seed: seed for this view (derived from the loop's seed and the view index).
        camera: the camera (``proctex.texture.render.Camera``), for painters that need intrinsics.
        part: (H, W) int64 part id per pixel, -1 on background (or None).
        extra: anything else the loop knows (``group_labels``: {group id: label}).
    """

    prompt: str
    group_prompts: dict[int, str]
    rgb: np.ndarray
    trimap: np.ndarray
    depth: np.ndarray
    normal: np.ndarray
    points: np.ndarray
    group: np.ndarray
    center: np.ndarray
    scale: float
    view_index: int = 0
    n_views: int = 1
    seed: int = 0
    camera: Any = None
    part: np.ndarray | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def size(self) -> tuple[int, int]:
        return self.trimap.shape[0], self.trimap.shape[1]

    @property
    def foreground(self) -> np.ndarray:
        """(H, W) bool: pixels with surface."""
        return self.trimap != BACKGROUND

    @property
    def paint_mask(self) -> np.ndarray:
        """(H, W) bool: pixels the painter is asked to paint (REFINE or GENERATE)."""
        return self.trimap >= REFINE


@runtime_checkable
class ViewPainter(Protocol):
    """Paints one view: returns (H, W, 3) float32 RGB in [0, 1]; only ``request.paint_mask`` pixels are used."""

    def paint_view(self, request: ViewRequest) -> np.ndarray: ...
