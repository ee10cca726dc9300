"""Slow, obviously correct references of :mod:`proctex.texture.painters.noise` (loops over points, pixels or
texels), which the tests compare the shipped fast versions with; not used by the library."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from proctex.texture.painters.noise import _INV1023, _hash_cell, _octave_seed, _perlin_scalar, derive_seed, seed_key, split_points


def perlin_reference(points: np.ndarray, freq: float | Sequence[float] = 1.0, seed: int = 0) -> np.ndarray:
    """Slow reference of :func:`perlin`: loops over points and the 8 lattice corners. ``(n,) float64``."""
    x, y, z = split_points(points, freq)
    key = seed_key(seed)
    return np.array([_perlin_scalar(float(a), float(b), float(c), key) for a, b, c in zip(x, y, z)])


def _fractal_reference(points, freq, octaves, lacunarity, gain, seed, kind):
    x, y, z = split_points(points, freq)
    out = np.zeros(len(x))
    for i in range(len(x)):
        total, amp, norm, f = 0.0, 1.0, 0.0, 1.0
        for k in range(octaves):
            ff = np.float32(f)  # the fast path scales in float32: do the same to land in the same cell
            n = _perlin_scalar(float(x[i] * ff), float(y[i] * ff), float(z[i] * ff), seed_key(_octave_seed(seed, k)))
            if kind == "turbulence":
                n = abs(n)
            elif kind == "ridged":
                n = (1.0 - abs(n)) ** 2
            total += amp * n
            norm += amp
            amp *= gain
            f *= lacunarity
        out[i] = total / norm
    return out


def fbm_reference(points, freq=1.0, octaves=4, lacunarity=2.0, gain=0.5, seed=0) -> np.ndarray:
    """Slow reference of :func:`fbm`. ``(n,) float64``."""
    return _fractal_reference(points, freq, octaves, lacunarity, gain, seed, "fbm")


def turbulence_reference(points, freq=1.0, octaves=4, lacunarity=2.0, gain=0.5, seed=0) -> np.ndarray:
    """Slow reference of :func:`turbulence`. ``(n,) float64``."""
    return _fractal_reference(points, freq, octaves, lacunarity, gain, seed, "turbulence")


def ridged_reference(points, freq=1.0, octaves=4, lacunarity=2.0, gain=0.5, seed=0) -> np.ndarray:
    """Slow reference of :func:`ridged`. ``(n,) float64``."""
    return _fractal_reference(points, freq, octaves, lacunarity, gain, seed, "ridged")


def worley_reference(points, freq=1.0, seed: int = 0, jitter: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Slow reference of :func:`worley`: every point, every one of the 27 cells, sorted distances."""
    x, y, z = split_points(points, freq)
    key = seed_key(seed)
    off = 0.5 * (1.0 - jitter)
    f1s, f2s, cells = [], [], []
    for px, py, pz in zip(x.astype(float), y.astype(float), z.astype(float)):
        ix, iy, iz = math.floor(px), math.floor(py), math.floor(pz)
        found = []
        for a in (-1, 0, 1):
            for b in (-1, 0, 1):
                for c in (-1, 0, 1):
                    h = _hash_cell(ix + a, iy + b, iz + c, key)
                    fp = (
                        ix + a + off + (h & 1023) * _INV1023 * jitter,
                        iy + b + off + ((h >> 10) & 1023) * _INV1023 * jitter,
                        iz + c + off + (h >> 22) * _INV1023 * jitter,
                    )
                    found.append((math.dist((px, py, pz), fp), h))
        found.sort(key=lambda t: t[0])
        f1s.append(found[0][0])
        f2s.append(found[1][0])
        cells.append((found[0][1] >> 8) / float(1 << 24))
    return np.array(f1s), np.array(f2s), np.array(cells)


def domain_warp_reference(points, freq=1.0, amount: float = 0.5, octaves: int = 2, seed: int = 0) -> np.ndarray:
    """Slow reference of :func:`domain_warp`. ``(n, 3) float64``."""
    p = np.stack(split_points(points, freq), axis=1)
    out = p.astype(float).copy()
    for k in range(3):
        out[:, k] += amount * fbm_reference(p, 1.0, octaves=octaves, seed=derive_seed(seed, f"warp{k}"))
    return out
