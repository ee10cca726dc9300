"""Physically based shading of rendered views: what a PBR viewer shows, so a person sees the maps.

:func:`pbr_surface` gathers, per pixel of a view (:class:`proctex.texture.render.Buffers`), the
base colour, roughness, metalness and the shading normal (the smooth vertex normal bent by the
tangent-space normal map in the interpolated tangent frame, :func:`proctex.texture.pbr.corner_tangents`,
the same frame the GLB carries). :func:`shade_pbr` lights it the way glTF's metallic-roughness model
asks:

- a Cook-Torrance GGX specular lobe (Smith-Schlick visibility, Schlick Fresnel, F0 = 0.04 for
  dielectrics and the base colour for metals) and a Lambert diffuse lobe (none for metals), under a
  key light, a fill light and a rim light;
- image-based light from a studio environment (a sky-to-floor gradient with a soft box overhead),
  pre-blurred by roughness, with Karis's analytic split-sum term for the specular part.

Colours are linearised from sRGB, shaded in linear light, tone-mapped (Reinhard on luminance) and
encoded back. Everything is per pixel in NumPy; there is no shadowing or inter-reflection.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from .pbr import corner_normals, corner_tangents, decode_normal, surface_frames
from .uv import sample_texture

__all__ = ["pbr_surface", "shade_pbr", "environment", "vertex_occlusion"]

_SKY = np.array([0.95, 0.97, 1.0])
_FLOOR = np.array([0.22, 0.2, 0.18])
_BOX = 5.0  # soft box radiance over the sky


def _srgb_to_linear(c: np.ndarray) -> np.ndarray:
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _linear_to_srgb(c: np.ndarray) -> np.ndarray:
    c = np.clip(c, 0.0, 1.0)
    return np.where(c <= 0.0031308, c * 12.92, 1.055 * c ** (1 / 2.4) - 0.055)


def _smooth(e0: float | np.ndarray, e1: float | np.ndarray, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def environment(directions: np.ndarray, up: np.ndarray, roughness: np.ndarray | float = 0.0) -> np.ndarray:
    """Linear radiance (n, 3) of the studio environment seen along unit ``directions`` (n, 3),
    pre-blurred for ``roughness`` (n,) in [0, 1]: a gradient from the floor to the sky and a soft box
    overhead whose edge widens (and whose peak falls, keeping its energy) as the surface roughens."""
    d = np.asarray(directions, dtype=np.float64)
    r = np.broadcast_to(np.asarray(roughness, dtype=np.float64), (len(d),))
    h = d @ up
    blur = 0.25 + 0.75 * r
    base = _FLOOR + (_SKY - _FLOOR) * _smooth(-0.35 * blur, 0.6 * blur + 0.05, h)[:, None]
    width = 0.05 + 0.9 * r * r
    box = _BOX * (0.05 / width) * _smooth(1.0 - width, 1.0 - 0.3 * width, h)
    return base * 0.8 + box[:, None]


def pbr_surface(
    buffers: Any,
    vertices: np.ndarray,
    faces: np.ndarray,
    corner_uv: np.ndarray,
    face_group: np.ndarray,
    textures: Sequence[np.ndarray],
    maps: Sequence[Any] | None = None,
    normals: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """Per seen pixel (``buffers.mask``): ``albedo`` (k, 3) sRGB, ``roughness`` (k,), ``metallic`` (k,),
    ``occlusion`` (k,) (1 where no map holds any) and the world ``normal`` (k, 3), bent by the normal
    maps of the groups that have them.

    ``maps``: per texture its :class:`proctex.texture.pbr.PbrMaps` or None (colour only: roughness
    0.8, not metal, the smooth normal). ``normals``: (m, 3, 3) per-corner unit normals (a file's
    own, e.g. :attr:`proctex.texture.gltf_read.TexturedMesh.corner_normals`); default the smooth
    vertex normals (:func:`proctex.texture.pbr.corner_normals`, what the GLB writes). Inputs as in
    :func:`proctex.texture.render.render_textured`.
    """
    m = buffers.mask
    face = buffers.face[m]
    bary = buffers.bary[m]
    fg = np.asarray(face_group)[face]
    uv = np.einsum("ij,ijk->ik", bary, np.asarray(corner_uv)[face])
    cn = corner_normals(vertices, faces) if normals is None else np.asarray(normals, dtype=np.float64)
    n = np.einsum("ij,ijk->ik", bary, cn[face])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    # Face the camera (double-sided materials): flip where the geometric normal was flipped.
    flip = (n * buffers.normal[m]).sum(1) < 0
    n[flip] *= -1
    k = int(m.sum())
    albedo = np.full((k, 3), 0.7)
    rough = np.full(k, 0.8)
    metal = np.zeros(k)
    occl = np.ones(k)
    tangents = None
    for g, tex in enumerate(textures):
        sel = fg == g
        if not sel.any():
            continue
        albedo[sel] = sample_texture(tex, uv[sel])[:, :3]
        mp = maps[g] if maps is not None and g < len(maps) else None
        if mp is None:
            continue
        orm = sample_texture(mp.orm_uint8(), uv[sel])
        rough[sel], metal[sel] = orm[:, 1], orm[:, 2]
        if mp.occlusion:
            occl[sel] = orm[:, 0]
        if tangents is None:
            tangents = corner_tangents(vertices, faces, corner_uv, cn)
        T, B, _ = surface_frames(face[sel], bary[sel], tangents, cn)  # the frame the map was baked in
        N = n[sel]  # turned to the camera: the bitangent keeps its texture-space direction
        nt = decode_normal(sample_texture(mp.normal_uint8(), uv[sel]))
        bent = nt[:, :1] * T + nt[:, 1:2] * B + nt[:, 2:] * N
        n[sel] = bent / np.maximum(np.linalg.norm(bent, axis=1, keepdims=True), 1e-12)
    return {"albedo": albedo, "roughness": rough, "metallic": metal, "normal": n, "occlusion": occl}


def _ggx(n_h: np.ndarray, n_v: np.ndarray, n_l: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Specular D * Vis (Smith-Schlick) of GGX, per pixel (k,)."""
    a2 = alpha * alpha
    d = a2 / (np.pi * (n_h * n_h * (a2 - 1.0) + 1.0) ** 2)
    kk = alpha / 2.0
    vis = 1.0 / ((n_v * (1 - kk) + kk) * (n_l * (1 - kk) + kk) * 4.0)
    return d * vis


def shade_pbr(buffers: Any, surface: dict[str, np.ndarray], up: np.ndarray | None = None, background=(1.0, 1.0, 1.0), exposure: float = 1.0) -> np.ndarray:
    """(H, W, 3) uint8 image of a view lit by key, fill and rim lights and the studio environment.

    ``surface``: :func:`pbr_surface`'s per-pixel values; ``up``: (3,) world up (default the camera's).
    """
    cam = buffers.camera
    right, _, fwd = cam.basis()
    up = np.asarray(cam.up if up is None else up, dtype=np.float64)
    up = up / np.linalg.norm(up)
    m = buffers.mask
    n = surface["normal"]
    v = np.asarray(cam.eye) - buffers.points[m]
    v /= np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12)
    base = _srgb_to_linear(np.clip(surface["albedo"], 0, 1))
    rough = np.clip(surface["roughness"], 0.04, 1.0)
    metal = np.clip(surface["metallic"], 0.0, 1.0)[:, None]
    f0 = 0.04 * (1 - metal) + base * metal
    diffuse_col = base * (1 - metal)
    n_v = np.clip((n * v).sum(1), 1e-4, 1.0)
    alpha = rough * rough
    out = np.zeros_like(base)
    # Lights: key from the upper front-left, fill from the right, rim from behind (radiance, direction).
    lights = [(1.8, 0.55 * up - 0.6 * right - 0.55 * fwd), (0.45, 0.2 * up + 0.9 * right - 0.3 * fwd), (1.0, 0.4 * up + 0.2 * right + 0.9 * fwd)]
    for radiance, direction in lights:
        ld = direction / np.linalg.norm(direction)
        n_l = np.clip(n @ ld, 0.0, 1.0)
        h = v + ld
        h /= np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-12)
        n_h = np.clip((n * h).sum(1), 0.0, 1.0)
        v_h = np.clip((v * h).sum(1), 0.0, 1.0)
        fres = f0 + (1 - f0) * ((1 - v_h) ** 5)[:, None]
        spec = fres * (_ggx(n_h, n_v, np.maximum(n_l, 1e-4), alpha) * n_l)[:, None]
        out += radiance * (diffuse_col / np.pi * n_l[:, None] * (1 - fres) + spec)
    # Image-based light: diffuse irradiance from the gradient, specular from the blurred environment.
    irr = environment(n, up, 1.0)
    r = 2.0 * n_v[:, None] * n - v
    pre = environment(r, up, rough)
    c0 = np.array([-1.0, -0.0275, -0.572, 0.022])
    c1 = np.array([1.0, 0.0425, 1.04, -0.04])
    rr = rough[:, None] * c0 + c1
    a004 = np.minimum(rr[:, 0] ** 2, np.exp2(-9.28 * n_v)) * rr[:, 0] + rr[:, 1]
    env_a = -1.04 * a004 + rr[:, 2]
    env_b = 1.04 * a004 + rr[:, 3]
    ao = surface.get("occlusion", np.ones(len(n)))[:, None]  # ambient occlusion dims the image-based light only
    out += ao * (diffuse_col * irr * 0.5 + pre * (f0 * env_a[:, None] + env_b[:, None]))
    out *= exposure
    lum = out @ np.array([0.2126, 0.7152, 0.0722])
    out *= (1.0 / (1.0 + lum / 1.6))[:, None] * 1.25  # Reinhard on luminance, keeps hue
    img = np.empty(buffers.face.shape + (3,), dtype=np.float64)
    img[:] = background
    img[m] = _linear_to_srgb(out)
    return (np.clip(img, 0, 1) * 255).round().astype(np.uint8)


def vertex_occlusion(vertices: np.ndarray, faces: np.ndarray, rays: int = 48, reach: float = 0.15, seed: int = 0, normals: np.ndarray | None = None) -> np.ndarray:
    """Ambient occlusion per vertex ``(n,) float64`` in [0, 1] (1: open sky): the share of
    cosine-weighted hemisphere rays around the smooth normal that leave the mesh within ``reach`` times
    the bounding-box diagonal, with a sample set fixed by ``seed`` (the same for every vertex, turned
    into its frame). Rays are cast with Embree (trimesh); ``ValueError`` without it. ``normals``:
    (n, 3) vertex normals (default: area-weighted smooth normals)."""
    import trimesh

    if not getattr(trimesh.ray, "has_embree", False):
        raise ValueError("ambient occlusion needs ray casting: install embreex (trimesh's Embree backend)")
    if not 1 <= int(rays) <= 1024:
        raise ValueError(f"rays must be in [1, 1024], got {rays}")
    from trimesh.ray.ray_pyembree import RayMeshIntersector

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if normals is None:
        cn = corner_normals(v, f)
        normals = np.zeros_like(v)
        normals[f.reshape(-1)] = cn.reshape(-1, 3)
    n = np.asarray(normals, dtype=np.float64)
    diag = float(np.linalg.norm(v.max(0) - v.min(0))) or 1.0
    rng = np.random.default_rng(seed)
    u1, u2 = rng.random(rays), rng.random(rays)
    local = np.stack([np.sqrt(u1) * np.cos(2 * np.pi * u2), np.sqrt(u1) * np.sin(2 * np.pi * u2), np.sqrt(1 - u1)], 1)  # cosine-weighted
    helper = np.where(np.abs(n[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    t = np.cross(n, helper)
    t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-12)
    b = np.cross(n, t)
    dirs = (local[None, :, :1] * t[:, None] + local[None, :, 1:2] * b[:, None] + local[None, :, 2:] * n[:, None]).reshape(-1, 3)
    origins = np.repeat(v + n * (1e-4 * diag), rays, axis=0)
    hit = np.zeros(len(dirs), dtype=bool)
    intersector = RayMeshIntersector(trimesh.Trimesh(v, f, process=False, validate=False))
    chunk = 262144
    for s in range(0, len(dirs), chunk):
        loc, ray, _ = intersector.intersects_location(origins[s : s + chunk], dirs[s : s + chunk], multiple_hits=False)
        if len(ray):
            near = np.linalg.norm(loc - origins[s + ray], axis=1) < reach * diag
            hit[s + ray[near]] = True
    return 1.0 - hit.reshape(len(v), rays).mean(axis=1)
