"""Quick shaded previews of shapes by ray casting (for looking at models and segmentations).

Uses trimesh's ray intersector (embree when installed, else the pure-Python one). Colours come from
a per-face colour array (parts, groups or semantic labels), shaded by the view cosine.
"""

from __future__ import annotations

import numpy as np
import trimesh

from .shape import Shape

PALETTE = np.array(
    [
        [0.90, 0.55, 0.35],
        [0.35, 0.60, 0.85],
        [0.55, 0.80, 0.45],
        [0.85, 0.40, 0.55],
        [0.95, 0.80, 0.35],
        [0.60, 0.45, 0.80],
        [0.40, 0.80, 0.80],
        [0.75, 0.75, 0.75],
        [0.95, 0.60, 0.75],
        [0.50, 0.55, 0.30],
        [0.30, 0.40, 0.60],
        [0.80, 0.30, 0.25],
    ]
)


def look_at_rays(center: np.ndarray, radius: float, azimuth: float, elevation: float, size: int, fov_deg: float = 35.0):
    """Ray origins and directions, each (size*size, 3) float64, for a camera orbiting ``center``.

    The camera sits at distance fitting a sphere of ``radius`` in view, looking at ``center``;
    +z is up, azimuth and elevation in degrees.
    """
    az, el = np.radians(azimuth), np.radians(elevation)
    direction = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    dist = radius / np.sin(np.radians(fov_deg) / 2)
    eye = center + direction * dist
    fwd = -direction
    up = np.array([0.0, 0.0, 1.0])
    right = np.cross(fwd, up)
    if np.linalg.norm(right) < 1e-8:
        right = np.array([0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    true_up = np.cross(right, fwd)
    half = np.tan(np.radians(fov_deg) / 2)
    xs = (np.arange(size) + 0.5) / size * 2 - 1
    gx, gy = np.meshgrid(xs * half, -xs * half)
    dirs = fwd[None] + gx.reshape(-1, 1) * right[None] + gy.reshape(-1, 1) * true_up[None]
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    return np.repeat(eye[None], len(dirs), axis=0), dirs


def render_faces(
    vertices: np.ndarray,
    faces: np.ndarray,
    face_colors: np.ndarray,
    size: int = 256,
    azimuth: float = 35.0,
    elevation: float = 25.0,
    background: float = 1.0,
) -> np.ndarray:
    """(size, size, 3) uint8 image of the mesh with flat per-face colours ``(m, 3)`` in [0, 1]."""
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    center = (lo + hi) / 2
    radius = max(np.linalg.norm(hi - lo) / 2, 1e-9)
    origins, dirs = look_at_rays(center, radius, azimuth, elevation, size)
    tri, ray, _ = mesh.ray.intersects_id(origins, dirs, multiple_hits=False, return_locations=True)
    img = np.full((size * size, 3), background)
    normals = mesh.face_normals[tri]
    cos = np.abs(np.einsum("ij,ij->i", normals, dirs[ray]))
    shade = 0.25 + 0.75 * cos
    img[ray] = np.clip(face_colors[tri] * shade[:, None], 0, 1)
    return (img.reshape(size, size, 3) * 255).round().astype(np.uint8)


def face_label_colors(shape: Shape) -> np.ndarray:
    """(m, 3) colours by semantic label (or uniform grey when the shape has none)."""
    if shape.labels is None:
        return np.full((shape.n_faces, 3), 0.75)
    return PALETTE[shape.labels[shape.faces[:, 0]] % len(PALETTE)]


def grid_image(images: list[list[np.ndarray]], pad: int = 4) -> np.ndarray:
    """Tile rows of equally sized (h, w, 3) uint8 images into one image with white padding."""
    rows = len(images)
    cols = max(len(r) for r in images)
    h, w, _ = images[0][0].shape
    out = np.full((rows * (h + pad) + pad, cols * (w + pad) + pad, 3), 255, dtype=np.uint8)
    for i, row in enumerate(images):
        for j, im in enumerate(row):
            y, x = pad + i * (h + pad), pad + j * (w + pad)
            out[y : y + h, x : x + w] = im
    return out
