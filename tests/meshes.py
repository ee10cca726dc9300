"""Small hand-built meshes for tests."""

import numpy as np

from proctex import primitives as P


def cube(center=(0.0, 0.0, 0.0), size=1.0):
    """8-vertex closed cube: (vertices (8, 3), faces (12, 3)) with outward winding."""
    part = P.box((size, size, size), center=center)
    return part.vertices, part.faces


def two_cubes_touching():
    """Two unit cubes sharing the face x = 0.5 (coincident vertices, separate indices)."""
    va, fa = cube((0, 0, 0))
    vb, fb = cube((1, 0, 0))
    return np.concatenate([va, vb]), np.concatenate([fa, fb + len(va)])


def soup(vertices, faces):
    """Every face gets its own three vertices (no shared index at all)."""
    return vertices[faces].reshape(-1, 3), np.arange(len(faces) * 3).reshape(-1, 3)
