"""Painters: turn a prompt into colour (docs/texturing.md).

- :class:`SurfacePainter` (offline default): colours texels from their 3D position and normal with solid
  procedural materials read from the prompt (:func:`parse_prompt` -> :class:`MaterialSpec`).
- View painters (:class:`ViewPainter`, fed :class:`ViewRequest`) paint rendered views inside the
  multi-view loop; the diffusion-backed one lives in :mod:`proctex.texture.painters.diffusion` and is imported
  from there (it needs optional dependencies).
"""

from .base import BACKGROUND, GENERATE, KEEP, REFINE, ViewPainter, ViewRequest
from .prompt import MaterialSpec, parse_prompt
from .surface import SurfacePainter

__all__ = [
    "SurfacePainter",
    "parse_prompt",
    "MaterialSpec",
    "ViewPainter",
    "ViewRequest",
    "BACKGROUND",
    "KEEP",
    "REFINE",
    "GENERATE",
]
