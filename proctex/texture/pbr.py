"""PBR maps of a group texture: occlusion-roughness-metallic and a tangent-space normal map.

A group's material is its base-colour image plus, here, two more images over the same UV layout
(:class:`PbrMaps`):

- ``orm``: glTF's packing, R ambient occlusion (1: none), G perceptual roughness, B metalness. The
  GLB points its ``metallicRoughnessTexture`` (G, B) and ``occlusionTexture`` (R) at the same image.
- ``normal``: a tangent-space normal map, encoded ``n * 0.5 + 0.5``, +X along increasing u, +Y along
  increasing v (v up, OpenGL and glTF convention), +Z out of the surface.

Tangent frames are per corner (:func:`corner_tangents`): per (vertex, UV) pair, the area-weighted
directions of increasing u on the faces around it, made orthogonal to the smooth vertex normal, with a
handedness sign ``w`` so that the bitangent is ``w * cross(N, T)``. The GLB writes exactly these as its
TANGENT attribute, and :func:`bake_normals` and the renderer interpolate the same corners, so a viewer
decodes the normal map in the frame it was baked in. Because maps live in tangent space, a transferred
shape that reads the template's UVs gets the same relief without recomputing anything.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from proctex.geometry.rowmath import cross3, dot3

from .uv import TexelMap, pad_seams

__all__ = [
    "PbrMaps",
    "corner_tangents",
    "key_tangents",
    "corner_normals",
    "vertex_normals",
    "area_normals",
    "texel_frames",
    "surface_frames",
    "encode_normal",
    "decode_normal",
    "bake_maps",
    "flat_maps",
    "FLAT_NORMAL",
]

#: the encoded colour of an unperturbed normal (0, 0, 1).
FLAT_NORMAL = (0.5, 0.5, 1.0)


@dataclass
class PbrMaps:
    """The PBR maps of one group texture.

    Attributes:
        orm: (H, W, 3) float32 in [0, 1]: R occlusion, G roughness, B metallic.
        normal: (H, W, 3) float32 in [0, 1]: the encoded tangent-space normal (:func:`encode_normal`).
        occlusion: whether R holds baked ambient occlusion (False: R is 1).
    """

    orm: np.ndarray
    normal: np.ndarray
    occlusion: bool = False

    def orm_uint8(self) -> np.ndarray:
        """(H, W, 3) uint8 ORM image."""
        return _to_uint8(self.orm)

    def normal_uint8(self) -> np.ndarray:
        """(H, W, 3) uint8 normal map."""
        return _to_uint8(self.normal)

    @property
    def roughness(self) -> np.ndarray:
        """(H, W) float32 roughness."""
        return self.orm[..., 1]

    @property
    def metallic(self) -> np.ndarray:
        """(H, W) float32 metalness."""
        return self.orm[..., 2]


def _to_uint8(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    if image.dtype == np.uint8:
        return image
    return (np.clip(image, 0, 1) * 255).round().astype(np.uint8)


def flat_maps(height: int, width: int, roughness: float = 0.8, metallic: float = 0.0) -> PbrMaps:
    """Uniform maps (H, W): constant roughness and metalness, no occlusion, a flat normal."""
    orm = np.empty((height, width, 3), np.float32)
    orm[:] = (1.0, roughness, metallic)
    normal = np.empty((height, width, 3), np.float32)
    normal[:] = FLAT_NORMAL
    return PbrMaps(orm, normal)


def encode_normal(n: np.ndarray) -> np.ndarray:
    """Unit tangent-space normals (..., 3) -> colours in [0, 1] (``n * 0.5 + 0.5``)."""
    return np.clip(np.asarray(n, dtype=np.float32) * 0.5 + 0.5, 0.0, 1.0)


def decode_normal(c: np.ndarray) -> np.ndarray:
    """Colours (..., 3) in [0, 1] (or uint8) -> unit tangent-space normals (float64)."""
    c = np.asarray(c)
    c = c.astype(np.float64) / 255.0 if c.dtype == np.uint8 else c.astype(np.float64)
    n = c * 2.0 - 1.0
    length = np.linalg.norm(n, axis=-1, keepdims=True)
    return np.divide(n, length, out=np.broadcast_to(np.array([0.0, 0.0, 1.0]), n.shape).copy(), where=length > 1e-12)


# ---------------------------------------------------------------------------------------- tangents
def _uv_keys(faces: np.ndarray, corner_uv: np.ndarray) -> np.ndarray:
    """(m*3,) int64 id of each corner's (vertex, float32 UV) pair, the pair the GLB splits vertices by."""
    st = np.ascontiguousarray(corner_uv.reshape(-1, 2).astype(np.float32) + np.float32(0))
    _, st_inv = np.unique(st.view(np.int64).ravel(), return_inverse=True)
    _, key = np.unique(faces.reshape(-1).astype(np.int64) * (int(st_inv.max()) + 1) + st_inv.ravel(), return_inverse=True)
    return key.ravel()


def area_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(m, 3) float64 unnormalised face normals (twice the area long) of ``faces (m, 3)``; compiled
    (:mod:`proctex.texture.vertex_kernels`), the same bits as :func:`area_normals_arrays` (which answers where numba does not import)."""
    try:
        from .vertex_kernels import area_normals as compiled
    except ImportError:  # no numba: the array form
        compiled = area_normals_arrays
    return compiled(vertices, faces)


def area_normals_arrays(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """:func:`area_normals` in array operations (the compiled form's reference)."""
    tri = np.asarray(vertices, dtype=np.float64)[np.asarray(faces, dtype=np.int64)]
    return cross3(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])


def vertex_normals(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
    """(n, 3) float64 area-weighted smooth vertex normals over the given faces only (the GLB's
    NORMAL); a vertex whose faces cancel, or that no face uses, gets +z. ``normals``: the faces'
    :func:`area_normals` when the caller has them. Compiled (:mod:`proctex.texture.vertex_kernels`),
    the same bits as :func:`vertex_normals_arrays` (which answers where numba does not import)."""
    try:
        from .vertex_kernels import vertex_normals as compiled
    except ImportError:  # no numba: the array form
        compiled = vertex_normals_arrays
    return compiled(vertices, faces, normals)


def vertex_normals_arrays(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
    """:func:`vertex_normals` in array operations (the compiled form's reference)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    fn = area_normals_arrays(v, f) if normals is None else normals
    flat = f.reshape(-1)
    acc = np.stack([np.bincount(flat, weights=np.repeat(fn[:, k], 3), minlength=len(v)) for k in range(3)], axis=1)
    length = np.sqrt(dot3(acc, acc))
    ok = length > 0
    acc[ok] /= length[ok, None]
    acc[~ok] = (0.0, 0.0, 1.0)
    return acc


def corner_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(m, 3, 3) float64 :func:`vertex_normals` at each corner of ``faces``."""
    return vertex_normals(vertices, faces)[np.asarray(faces, dtype=np.int64)]


def corner_tangents(vertices: np.ndarray, faces: np.ndarray, corner_uv: np.ndarray, normals: np.ndarray | None = None, keys: np.ndarray | None = None) -> np.ndarray:
    """Per-corner tangent frames ``(m, 3, 4)`` float64: unit tangent xyz (orthogonal to the corner's
    normal) and handedness w = ±1, shared by every corner of the same (vertex, UV) pair.

    Args:
        vertices: (n, 3); faces: (m, 3); corner_uv: (m, 3, 2) with v up.
        normals: (m, 3, 3) per-corner unit normals (default :func:`corner_normals` over ``faces``).
        keys: (m * 3,) int ids of the corners' (vertex, UV) pairs when the caller has them (the GLB's
            split vertices); default: computed from ``faces`` and the float32 UVs.
    A pair whose faces have no UV extent gets any tangent orthogonal to its normal, w = 1.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    uv = np.asarray(corner_uv, dtype=np.float64)
    if f.ndim != 2 or f.shape[1] != 3 or uv.shape != (len(f), 3, 2):
        raise ValueError(f"faces (m, 3) and corner_uv (m, 3, 2) expected, got {f.shape} and {uv.shape}")
    m = len(f)
    if m == 0:
        return np.zeros((0, 3, 4))
    nrm = corner_normals(v, f) if normals is None else np.asarray(normals, dtype=np.float64)
    key = _uv_keys(f, uv) if keys is None else np.asarray(keys, dtype=np.int64).reshape(-1)
    n_keys = int(key.max()) + 1
    key_normals = np.zeros((n_keys, 3))
    key_normals[key] = nrm.reshape(-1, 3)  # every corner of a pair has its vertex's normal
    return key_tangents(v, f, uv, key, key_normals)[key].reshape(m, 3, 4)


def key_tangents(vertices: np.ndarray, faces: np.ndarray, corner_uv: np.ndarray, keys: np.ndarray, key_normals: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
    """The tangent frame ``(k, 4)`` of each (vertex, UV) pair: ``keys`` (m * 3,) gives each corner's
    pair, ``key_normals`` (k, 3) each pair's unit normal; ``normals``: the faces'
    :func:`area_normals` when the caller has them. See :func:`corner_tangents`. Compiled
    (:mod:`proctex.texture.vertex_kernels`), the same bits as :func:`key_tangents_arrays` (which answers where numba does not import)."""
    try:
        from .vertex_kernels import key_tangents as compiled
    except ImportError:  # no numba: the array form
        compiled = key_tangents_arrays
    return compiled(vertices, faces, corner_uv, keys, key_normals, normals)


def key_tangents_arrays(vertices: np.ndarray, faces: np.ndarray, corner_uv: np.ndarray, keys: np.ndarray, key_normals: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
    """:func:`key_tangents` in array operations: the reference its compiled form is checked against."""
    v, f, uv = vertices, faces, corner_uv
    tri = v[f]
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    d1, d2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    ok = np.abs(det) > 1e-20
    r = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    t = (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) * r[:, None]  # dP/du
    b = (e2 * d1[:, 0:1] - e1 * d2[:, 0:1]) * r[:, None]  # dP/dv
    fn = cross3(e1, e2) if normals is None else normals
    area = 0.5 * np.sqrt(dot3(fn, fn))
    for a in (t, b):  # unit directions weighted by area: a stretched face must not dominate
        length = np.sqrt(dot3(a, a))
        a *= (area / np.where(length > 1e-30, length, 1.0))[:, None]
    n_keys = len(key_normals)
    T = np.stack([np.bincount(keys, weights=np.repeat(t[:, k], 3), minlength=n_keys) for k in range(3)], axis=1)
    B = np.stack([np.bincount(keys, weights=np.repeat(b[:, k], 3), minlength=n_keys) for k in range(3)], axis=1)
    N = key_normals
    T -= N * dot3(T, N)[:, None]
    length = np.sqrt(dot3(T, T))
    bad = length < 1e-12
    if bad.any():  # no UV extent: any direction in the tangent plane
        n = N[bad]
        helper = np.where(np.abs(n[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
        T[bad] = helper - n * (helper * n).sum(1, keepdims=True)
        length = np.sqrt(dot3(T, T))
    T /= np.maximum(length, 1e-300)[:, None]
    w = np.where(dot3(cross3(N, T), B) < 0, -1.0, 1.0)
    return np.concatenate([T, w[:, None]], axis=1)


def texel_frames(texels: TexelMap, tangents: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Interpolated, orthonormalised frames at covered texels: ``(T, B, N)``, each (t, 3) float64.

    ``tangents``: (k, 3, 4) per corner (:func:`corner_tangents`) and ``normals``: (k, 3, 3) per corner,
    of the faces ``texels`` was made from. The bitangent is ``w * cross(N, T)``, as a viewer builds it."""
    return surface_frames(texels.face, texels.bary, tangents, normals)


def surface_frames(face: np.ndarray, bary: np.ndarray, tangents: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Interpolated, orthonormalised frames ``(T, B, N)`` (t, 3) at surface points given by ``face``
    (t,) and barycentrics ``bary`` (t, 3): the per-corner ``tangents`` (k, 3, 4) and ``normals``
    (k, 3, 3) interpolated as a viewer does (texels, rendered pixels)."""
    bary = np.asarray(bary)[:, :, None]
    N = (normals[face] * bary).sum(1)
    N /= np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-300)
    tw = tangents[face]
    T = (tw[..., :3] * bary).sum(1)
    T -= N * (T * N).sum(1, keepdims=True)
    T /= np.maximum(np.linalg.norm(T, axis=1, keepdims=True), 1e-300)
    w = np.where(tw[:, 0, 3] < 0, -1.0, 1.0)
    B = np.cross(N, T) * w[:, None]
    return T, B, N


# ---------------------------------------------------------------------------------------- baking
def bake_maps(
    texels: TexelMap, vertices: np.ndarray, faces: np.ndarray, corner_uv: np.ndarray, props, center: np.ndarray, scale: float, gutter: int = 8, occlusion: np.ndarray | None = None
) -> PbrMaps:
    """Bake one group's maps at its covered texels.

    Args:
        texels: the texel map of ``faces`` (k, 3) over ``vertices`` with ``corner_uv`` (k, 3, 2).
        props: ``props(points (t, 3), normals (t, 3), tangents (t, 3), bitangents (t, 3)) ->
            (roughness (t,), metallic (t,), normal (t, 3))``, points in the normalised frame ``(p -
            center) / scale``, the normal in tangent space (e.g. :meth:`SurfacePainter.material`).
        gutter: seam padding in texels; occlusion: optional (t,) ambient occlusion per texel in [0, 1].
    Returns:
        :class:`PbrMaps` (texels outside the charts and their gutter: roughness 0.8, flat normal).
    """
    H, W = texels.height, texels.width
    maps = flat_maps(H, W)
    if len(texels.face) == 0:
        return maps
    cn = corner_normals(vertices, faces)
    T, B, N = texel_frames(texels, corner_tangents(vertices, faces, corner_uv, cn), cn)
    rough, metal, nts = props((texels.points - center) / scale, N, T, B)
    rough, metal, nts = np.asarray(rough, np.float32), np.asarray(metal, np.float32), np.asarray(nts, np.float32)
    t = len(texels.face)
    if rough.shape != (t,) or metal.shape != (t,) or nts.shape != (t, 3):
        raise ValueError(f"material props returned {rough.shape}, {metal.shape}, {nts.shape}; expected ({t},), ({t},), ({t}, 3)")
    if not (np.isfinite(rough).all() and np.isfinite(metal).all() and np.isfinite(nts).all()):
        raise ValueError("material props returned NaN or infinite values")
    ii, jj = texels.ij[:, 0], texels.ij[:, 1]
    maps.orm[ii, jj, 0] = 1.0 if occlusion is None else np.clip(occlusion, 0, 1)
    maps.orm[ii, jj, 1] = np.clip(rough, 0, 1)
    maps.orm[ii, jj, 2] = np.clip(metal, 0, 1)
    maps.normal[ii, jj] = encode_normal(nts)
    orm, _ = pad_seams(maps.orm, texels.mask, gutter)
    normal, _ = pad_seams(maps.normal, texels.mask, gutter)
    return PbrMaps(orm, normal, occlusion is not None)
