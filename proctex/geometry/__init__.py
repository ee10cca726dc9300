"""Geometry: meshes and what is measured on them.

``shape`` (the Shape record and the ProceduralModel interface), ``primitives`` (watertight parts with
canonical coordinates), ``meshio`` (OBJ / PLY / STL / GLB in and out), ``surface`` (closest points,
sampling, normals), ``align`` (Umeyama, ICP, Chamfer), ``parts`` (parts, groups, matching), ``raster``
(the triangle rasteriser) and ``preview`` (part-coloured previews). Imports nothing above it.
"""
