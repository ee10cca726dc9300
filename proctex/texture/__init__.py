"""Texture: everything that puts colour on a surface.

``uv`` (atlases, texel maps, seam padding), ``render`` (cameras, ray casting, shaded images),
``painters/`` (prompt to colours, the view-painter interface), ``paint`` (the paint loop), ``inpaint``
and ``edit`` (fills and edits), ``export`` (GLB / OBJ), ``metrics`` (coverage, view similarity) and
``lpips``. Imports ``geometry`` and the base modules only.
"""
