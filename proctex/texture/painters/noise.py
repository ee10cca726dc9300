"""Solid (3D) procedural noise: gradient noise, fractal sums, cellular noise, domain warping.

Every function is a pure function of the points and a seed: the same point always gets the same value,
whatever else is in the batch, so textures can be evaluated texel by texel, pixel by pixel or in
chunks and agree. Two layers:

- public functions take ``points (n, 3)`` (any float dtype) and return ``(n,) float32``:
  :func:`perlin`, :func:`fbm`, :func:`turbulence`, :func:`ridged`, :func:`worley`, :func:`domain_warp`;
- ``*_xyz`` kernels take the three coordinates as separate contiguous ``(n,) float32`` arrays (already
  multiplied by the frequency). They are what the painters call on cache-sized chunks: contiguous
  float32 arrays keep numpy in its SIMD loops.

Each fast function has a slow reference (:mod:`proctex._reference.noise`: plain Python loops over points and lattice
corners, float64) that the tests compare against.

Lattice hashing is arithmetic (no permutation-table gathers, which cost 5–20x an add in numpy): the
integer cell coordinates are multiplied by large odd constants, xor-ed with the seed's key and mixed
with the ``lowbias32`` finaliser. Gradients come from three 10-bit fields of the hash (uniform in the
cube, scaled so that the noise has unit-ish range). The lattice does not repeat.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Sequence

import numpy as np

__all__ = [
    "seed_key",
    "derive_seed",
    "perlin",
    "perlin_xyz",
    "fbm",
    "fbm_xyz",
    "turbulence",
    "turbulence_xyz",
    "ridged",
    "ridged_xyz",
    "worley",
    "worley_xyz",
    "domain_warp",
    "domain_warp_xyz",
    "cell_hash",
    "hash_unit",
    "split_points",
]

_MASK = 0xFFFFFFFF
_PX, _PY, _PZ = 0x8DA6B343, 0xD8163841, 0xCB1AB31F  # per-axis odd multipliers of the lattice hash
# Gradient components are (h_bits(10) - 511.5) * _GSCALE; _GSCALE makes the noise range about [-1, 1]
# (the std of one octave is about 0.2; see tests).
_GSCALE = np.float32(1.3 / 511.5)
_U32 = np.uint32


def _mix32(h: int) -> int:
    """lowbias32 finaliser on a Python int (the scalar twin of :func:`_mix32_array`)."""
    h &= _MASK
    h ^= h >> 16
    h = (h * 0x7FEB352D) & _MASK
    h ^= h >> 15
    h = (h * 0x846CA68B) & _MASK
    h ^= h >> 16
    return h


def _mix32_array(h: np.ndarray) -> np.ndarray:
    """lowbias32 finaliser on a uint32 array (in place; returns it)."""
    h ^= h >> _U32(16)
    h *= _U32(0x7FEB352D)
    h ^= h >> _U32(15)
    h *= _U32(0x846CA68B)
    h ^= h >> _U32(16)
    return h


def seed_key(seed: int) -> int:
    """32-bit key of an integer seed (any Python int, negative allowed)."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise ValueError(f"seed must be an int, got {type(seed).__name__}")
    s = int(seed)
    return _mix32(_mix32(s & _MASK) ^ ((s >> 32) & _MASK) ^ 0x9E3779B9)


def derive_seed(seed: int, salt: str | int) -> int:
    """A new seed from ``seed`` and a salt (stable across runs: uses crc32, not Python's ``hash``)."""
    salt_int = zlib.crc32(salt.encode()) if isinstance(salt, str) else int(salt) & _MASK
    return _mix32(seed_key(seed) ^ _mix32(salt_int + 0x632BE5AB))


def _fade(t: np.ndarray) -> np.ndarray:
    """Quintic fade 6t^5 - 15t^4 + 10t^3 (C2-continuous interpolation weights); new array."""
    f = t * np.float32(6.0)
    f -= np.float32(15.0)
    f *= t
    f += np.float32(10.0)
    f *= t
    f *= t
    f *= t
    return f


def split_points(points: np.ndarray, freq: float | Sequence[float] = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``points (n, 3)`` times ``freq`` (scalar or per-axis) as three contiguous ``(n,) float32`` arrays."""
    p = np.asarray(points)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must have shape (n, 3), got {p.shape}")
    f = np.broadcast_to(np.asarray(freq, dtype=np.float32), (3,))
    return tuple(np.ascontiguousarray(p[:, k], dtype=np.float32) * f[k] for k in range(3))  # type: ignore[return-value]


# --------------------------------------------------------------------------------------------------
# Gradient (Perlin-style) noise
# --------------------------------------------------------------------------------------------------


def _grad_dot(h: np.ndarray, dx: np.ndarray, dy: np.ndarray, dz: np.ndarray) -> np.ndarray:
    """Dot of the hash's gradient with the offset (dx, dy, dz); all (n,), h uint32. In-place heavy:
    numpy temporaries cost as much as the arithmetic here."""
    g = (h & _U32(1023)).astype(np.float32)
    g -= np.float32(511.5)
    g *= dx
    t = ((h >> _U32(10)) & _U32(1023)).astype(np.float32)
    t -= np.float32(511.5)
    t *= dy
    g += t
    t = (h >> _U32(22)).astype(np.float32)
    t -= np.float32(511.5)
    t *= dz
    g += t
    return g


def _lerp(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """a + t (b - a), reusing ``b``'s buffer (b is consumed)."""
    b -= a
    b *= t
    b += a
    return b


def _lattice(x: np.ndarray, y: np.ndarray, z: np.ndarray, seed: int):
    """Lattice cells of points and their per-axis hash terms: ``(key, (fx, fy, fz), (hx, hy, hz))``.

    ``f*`` are the cell corners (float32 floors); ``h* = cell * prime`` as uint32 (int32 -> uint32 view:
    negative cells wrap, which is what the modular hash wants), with ``hx`` already keyed by the seed.
    """
    key = _U32(seed_key(seed))
    fx, fy, fz = np.floor(x), np.floor(y), np.floor(z)
    hx = fx.astype(np.int32).view(np.uint32) * _U32(_PX)
    hy = fy.astype(np.int32).view(np.uint32) * _U32(_PY)
    hz = fz.astype(np.int32).view(np.uint32) * _U32(_PZ)
    hx ^= key
    return key, (fx, fy, fz), (hx, hy, hz)


def perlin_xyz(x: np.ndarray, y: np.ndarray, z: np.ndarray, seed: int = 0) -> np.ndarray:
    """Gradient noise at (x, y, z), each ``(n,) float32`` (lattice units). Returns ``(n,) float32``.

    Zero at every lattice point, C2-continuous, range about [-1, 1], std about 0.2.
    """
    key, (fx, fy, fz), (hx0, hy0, hz0) = _lattice(x, y, z, seed)
    hx1 = (hx0 ^ key) + _U32(_PX)  # (ix + 1) * PX, then re-keyed below
    hx1 ^= key
    hy1 = hy0 + _U32(_PY)
    hz1 = hz0 + _U32(_PZ)
    x0, y0, z0 = x - fx, y - fy, z - fz
    x1, y1, z1 = x0 - np.float32(1.0), y0 - np.float32(1.0), z0 - np.float32(1.0)
    u, v, w = _fade(x0), _fade(y0), _fade(z0)

    def corner(hx, hy, hz, dx, dy, dz):
        return _grad_dot(_mix32_array(hx ^ hy ^ hz), dx, dy, dz)

    n000 = corner(hx0, hy0, hz0, x0, y0, z0)
    n100 = corner(hx1, hy0, hz0, x1, y0, z0)
    n010 = corner(hx0, hy1, hz0, x0, y1, z0)
    n110 = corner(hx1, hy1, hz0, x1, y1, z0)
    n001 = corner(hx0, hy0, hz1, x0, y0, z1)
    n101 = corner(hx1, hy0, hz1, x1, y0, z1)
    n011 = corner(hx0, hy1, hz1, x0, y1, z1)
    n111 = corner(hx1, hy1, hz1, x1, y1, z1)
    nx00 = _lerp(n000, n100, u)
    nx10 = _lerp(n010, n110, u)
    nx01 = _lerp(n001, n101, u)
    nx11 = _lerp(n011, n111, u)
    nxy0 = _lerp(nx00, nx10, v)
    nxy1 = _lerp(nx01, nx11, v)
    out = _lerp(nxy0, nxy1, w)
    out *= _GSCALE
    return out


def perlin(points: np.ndarray, freq: float | Sequence[float] = 1.0, seed: int = 0) -> np.ndarray:
    """Gradient noise of ``points (n, 3)`` scaled by ``freq`` (scalar or per-axis). ``(n,) float32``."""
    return perlin_xyz(*split_points(points, freq), seed=seed)


def _hash_cell(ix: int, iy: int, iz: int, key: int) -> int:
    """Scalar lattice hash, identical to the vectorised one."""
    return _mix32((((ix * _PX) & _MASK) ^ key) ^ ((iy * _PY) & _MASK) ^ ((iz * _PZ) & _MASK))


def _grad(h: int) -> tuple[float, float, float]:
    s = float(_GSCALE)
    return ((h & 1023) - 511.5) * s, (((h >> 10) & 1023) - 511.5) * s, ((h >> 22) - 511.5) * s


def _fade_scalar(t: float) -> float:
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


def _perlin_scalar(x: float, y: float, z: float, key: int) -> float:
    ix, iy, iz = math.floor(x), math.floor(y), math.floor(z)
    total = 0.0
    for cx in (0, 1):
        for cy in (0, 1):
            for cz in (0, 1):
                dx, dy, dz = x - (ix + cx), y - (iy + cy), z - (iz + cz)
                gx, gy, gz = _grad(_hash_cell(ix + cx, iy + cy, iz + cz, key))
                wx = _fade_scalar(1 - abs(dx))  # weight of this corner along each axis
                wy = _fade_scalar(1 - abs(dy))
                wz = _fade_scalar(1 - abs(dz))
                total += wx * wy * wz * (gx * dx + gy * dy + gz * dz)
    return total


# --------------------------------------------------------------------------------------------------
# Fractal sums
# --------------------------------------------------------------------------------------------------


def _octave_seed(seed: int, k: int) -> int:
    return seed if k == 0 else derive_seed(seed, k)


def _fractal_xyz(x, y, z, octaves, lacunarity, gain, seed, kind):
    if octaves < 1:
        raise ValueError(f"octaves must be >= 1, got {octaves}")
    total = np.zeros_like(x)
    amp, norm, f = 1.0, 0.0, 1.0
    for k in range(octaves):
        s = _octave_seed(seed, k)
        ff = np.float32(f)
        n = perlin_xyz(x * ff, y * ff, z * ff, seed=s) if k else perlin_xyz(x, y, z, seed=s)
        if kind == "turbulence":
            n = np.abs(n)
        elif kind == "ridged":
            n = np.float32(1.0) - np.abs(n)
            n *= n
        total += np.float32(amp) * n
        norm += amp
        amp *= gain
        f *= lacunarity
    total *= np.float32(1.0 / norm)
    return total


def fbm_xyz(x, y, z, octaves: int = 4, lacunarity: float = 2.0, gain: float = 0.5, seed: int = 0) -> np.ndarray:
    """Fractional Brownian motion: normalised sum of ``octaves`` gradient-noise octaves. ``(n,) float32``."""
    return _fractal_xyz(x, y, z, octaves, lacunarity, gain, seed, "fbm")


def turbulence_xyz(x, y, z, octaves: int = 4, lacunarity: float = 2.0, gain: float = 0.5, seed: int = 0) -> np.ndarray:
    """Turbulence: normalised sum of |noise| octaves, in [0, ~1]. ``(n,) float32``."""
    return _fractal_xyz(x, y, z, octaves, lacunarity, gain, seed, "turbulence")


def ridged_xyz(x, y, z, octaves: int = 4, lacunarity: float = 2.0, gain: float = 0.5, seed: int = 0) -> np.ndarray:
    """Ridged multifractal (simple form): normalised sum of (1 - |noise|)^2, in [0, 1]. ``(n,) float32``."""
    return _fractal_xyz(x, y, z, octaves, lacunarity, gain, seed, "ridged")


def fbm(points, freq=1.0, octaves: int = 4, lacunarity: float = 2.0, gain: float = 0.5, seed: int = 0) -> np.ndarray:
    """:func:`fbm_xyz` of ``points (n, 3)`` scaled by ``freq``. ``(n,) float32``."""
    return fbm_xyz(*split_points(points, freq), octaves=octaves, lacunarity=lacunarity, gain=gain, seed=seed)


def turbulence(points, freq=1.0, octaves: int = 4, lacunarity: float = 2.0, gain: float = 0.5, seed: int = 0) -> np.ndarray:
    """:func:`turbulence_xyz` of ``points (n, 3)`` scaled by ``freq``. ``(n,) float32``."""
    return turbulence_xyz(*split_points(points, freq), octaves=octaves, lacunarity=lacunarity, gain=gain, seed=seed)


def ridged(points, freq=1.0, octaves: int = 4, lacunarity: float = 2.0, gain: float = 0.5, seed: int = 0) -> np.ndarray:
    """:func:`ridged_xyz` of ``points (n, 3)`` scaled by ``freq``. ``(n,) float32``."""
    return ridged_xyz(*split_points(points, freq), octaves=octaves, lacunarity=lacunarity, gain=gain, seed=seed)


# --------------------------------------------------------------------------------------------------
# Cellular (Worley) noise
# --------------------------------------------------------------------------------------------------

_INV1023 = 1.0 / 1023.0


def worley_xyz(x, y, z, seed: int = 0, jitter: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cellular noise at (x, y, z) (lattice units; one feature point per unit cell, searched over the
    3x3x3 neighbouring cells).

    Args:
        x, y, z: ``(n,) float32``.
        jitter: in [0, 1]; 0 puts every feature point at its cell centre, 1 anywhere in the cell.
    Returns:
        ``(f1, f2, cell)``, each ``(n,) float32``: distance to the nearest and second-nearest feature
        point and a random value in [0, 1) identifying the nearest point's cell (constant per cell).
    """
    key, (fx, fy, fz), (hx, hy, hz) = _lattice(x, y, z, seed)
    rx, ry, rz = x - fx, y - fy, z - fz
    jit = np.float32(jitter * _INV1023)
    off = np.float32(0.5 * (1.0 - jitter))
    # Per-axis hashes and offsets (query minus cell corner) for the cell offsets -1, 0, +1.
    hxs = [((hx ^ key) - _U32(_PX)) ^ key, hx, ((hx ^ key) + _U32(_PX)) ^ key]
    hys = [hy - _U32(_PY), hy, hy + _U32(_PY)]
    hzs = [hz - _U32(_PZ), hz, hz + _U32(_PZ)]
    dxs = [rx + np.float32(1.0 - off), rx - off, rx - np.float32(1.0 + off)]
    dys = [ry + np.float32(1.0 - off), ry - off, ry - np.float32(1.0 + off)]
    dzs = [rz + np.float32(1.0 - off), rz - off, rz - np.float32(1.0 + off)]
    big = np.float32(1e9)
    f1 = np.full_like(x, big)
    f2 = np.full_like(x, big)
    cell = np.zeros(x.shape, dtype=np.uint32)
    for a in range(3):
        for b in range(3):
            hab = hxs[a] ^ hys[b]
            for c in range(3):
                h = _mix32_array(hab ^ hzs[c])
                d = (h & _U32(1023)).astype(np.float32)
                d *= jit
                d -= dxs[a]  # minus the offset to the feature point: squared below
                d *= d
                t = ((h >> _U32(10)) & _U32(1023)).astype(np.float32)
                t *= jit
                t -= dys[b]
                t *= t
                d += t
                t = (h >> _U32(22)).astype(np.float32)
                t *= jit
                t -= dzs[c]
                t *= t
                d += t
                np.minimum(f2, np.maximum(f1, d), out=f2)
                closer = d < f1
                np.copyto(cell, h, where=closer)
                np.minimum(f1, d, out=f1)
    np.sqrt(f1, out=f1)
    np.sqrt(f2, out=f2)
    ident = (cell >> _U32(8)).astype(np.float32) * np.float32(1.0 / (1 << 24))
    return f1, f2, ident


def worley(points, freq=1.0, seed: int = 0, jitter: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`worley_xyz` of ``points (n, 3)`` scaled by ``freq``: ``(f1, f2, cell)`` each ``(n,) float32``."""
    return worley_xyz(*split_points(points, freq), seed=seed, jitter=jitter)


# --------------------------------------------------------------------------------------------------
# Domain warping
# --------------------------------------------------------------------------------------------------


def domain_warp_xyz(x, y, z, amount: float = 0.5, octaves: int = 2, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points displaced by a vector fBm: ``p + amount * (fbm_a(p), fbm_b(p), fbm_c(p))``.

    ``x, y, z`` are ``(n,) float32`` in lattice units; returns three ``(n,) float32``.
    """
    a = np.float32(amount)
    return tuple(c + a * fbm_xyz(x, y, z, octaves=octaves, seed=derive_seed(seed, f"warp{k}")) for k, c in enumerate((x, y, z)))  # type: ignore[return-value]


def domain_warp(points, freq=1.0, amount: float = 0.5, octaves: int = 2, seed: int = 0) -> np.ndarray:
    """Warp ``points (n, 3)`` (scaled by ``freq``) by :func:`domain_warp_xyz`. Returns ``(n, 3) float32``
    in the scaled (lattice) units."""
    return np.stack(domain_warp_xyz(*split_points(points, freq), amount=amount, octaves=octaves, seed=seed), axis=1)


# --------------------------------------------------------------------------------------------------
# Lattice hashes for regular patterns (tiles, bricks, flowers)
# --------------------------------------------------------------------------------------------------


def cell_hash(ix: np.ndarray, iy: np.ndarray, iz: np.ndarray | int = 0, seed: int = 0) -> np.ndarray:
    """Random uint32 per integer cell; ``ix, iy`` (and ``iz``) are ``(n,)`` integer arrays (or float
    arrays of whole numbers). The same hash as the noise lattice. Returns ``(n,) uint32``."""
    key = _U32(seed_key(seed))
    h = np.asarray(ix).astype(np.int32).view(np.uint32) * _U32(_PX)
    h ^= key
    h ^= np.asarray(iy).astype(np.int32).view(np.uint32) * _U32(_PY)
    if not (np.isscalar(iz) and iz == 0):
        h ^= np.asarray(iz).astype(np.int32).view(np.uint32) * _U32(_PZ)
    return _mix32_array(h)


def hash_unit(h: np.ndarray, field: int = 0) -> np.ndarray:
    """A float32 in [0, 1) from one of three 10-bit fields (``field`` 0, 1, 2) of a uint32 hash ``(n,)``."""
    shift = (0, 10, 22)[field]
    return ((h >> _U32(shift)) & _U32(1023)).astype(np.float32) * np.float32(1.0 / 1024.0)
