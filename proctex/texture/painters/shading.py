"""What every pattern and material works on: one chunk of surface points (:class:`Ctx`, with its
lazily computed noise fields) and the colour helpers (component-major ``(3, n) float32`` colours).
See :mod:`proctex.texture.painters.materials` for the pipeline they serve."""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from . import noise as nz
from .colors import RGB
from .prompt import MaterialSpec

F32 = np.float32
TAU = F32(2.0 * math.pi)


@lru_cache(maxsize=4096)
def _derived(seed: int, name: str) -> int:
    return nz.derive_seed(seed, name)


@lru_cache(maxsize=4096)
def _offset(seed: int, name: str) -> tuple[float, float, float]:
    """A seeded domain offset in [0, 64)^3 lattice units (so regular patterns shift with the seed too)."""
    h = nz.seed_key(_derived(seed, name + "/offset"))
    return tuple(float(((h >> s) & 0x3FF) / 16.0) for s in (0, 10, 20))  # type: ignore[return-value]


class Ctx:
    """One chunk of points being shaded.

    Args:
        points: ``(n, 3) float32`` in the shape's normalised frame.
        normals: ``(n, 3) float32`` unit (zero rows allowed: equal triplanar weights).
        seed: texture seed.
        scale: feature-size multiplier of the spec (2: features twice as large).
    """

    def __init__(self, points: np.ndarray, normals: np.ndarray, seed: int, scale: float = 1.0):
        self.x, self.y, self.z = (np.ascontiguousarray(points[:, k], dtype=F32) for k in range(3))
        self.nx, self.ny, self.nz = (np.ascontiguousarray(normals[:, k], dtype=F32) for k in range(3))
        self.n = len(self.x)
        self.seed = int(seed)
        self.scale = float(scale)
        self._cache: dict = {}

    # -- coordinates and noise ------------------------------------------------------------------
    def seed_for(self, name: str) -> int:
        return _derived(self.seed, name)

    def coords(self, freq: float | tuple[float, float, float], name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Points times ``freq / scale`` (per axis if a tuple) plus a seeded offset named ``name``."""
        f = freq if isinstance(freq, tuple) else (freq, freq, freq)
        o = _offset(self.seed, name)
        return tuple(c * F32(fk / self.scale) + F32(ok) for c, fk, ok in zip((self.x, self.y, self.z), f, o))  # type: ignore[return-value]

    def noise(self, name: str, freq, octaves: int = 1, kind: str = "fbm") -> np.ndarray:
        """Cached fractal noise ``(n,) float32`` named ``name`` (same name and args: same array)."""
        key = ("noise", name, freq, octaves, kind)
        if key not in self._cache:
            x, y, z = self.coords(freq, name)
            s = self.seed_for(name)
            if octaves == 1 and kind == "fbm":
                v = nz.perlin_xyz(x, y, z, s)
            else:
                fn = {"fbm": nz.fbm_xyz, "turbulence": nz.turbulence_xyz, "ridged": nz.ridged_xyz}[kind]
                v = fn(x, y, z, octaves=octaves, seed=s)
            self._cache[key] = v
        return self._cache[key]

    def cells(self, name: str, freq: float, jitter: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cached cellular noise ``(f1, f2, cell)`` named ``name``."""
        key = ("cells", name, freq, jitter)
        if key not in self._cache:
            self._cache[key] = nz.worley_xyz(*self.coords(freq, name), seed=self.seed_for(name), jitter=jitter)
        return self._cache[key]

    def tri_weights(self, power: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Triplanar weights ``|n_k|^power`` normalised to sum 1, each ``(n,) float32``."""
        key = ("tri", power)
        if key not in self._cache:
            ws = []
            for c in (self.nx, self.ny, self.nz):
                a = c * c
                w = a.copy()
                for _ in range(power // 2 - 1):
                    w *= a
                w += F32(1e-6)
                ws.append(w)
            total = ws[0] + ws[1] + ws[2]
            self._cache[key] = tuple(w / total for w in ws)
        return self._cache[key]

    def planes(self, axis: str = "horizontal") -> list[tuple[np.ndarray, np.ndarray]]:
        """In-plane coordinates ``(u, v)`` of the three projection planes (normal along x, y, z).

        ``v`` is the "across" coordinate of horizontal bands: height (z) on the side planes, y on the top
        plane (so bands wrap over a front edge). ``axis`` rotates that choice for vertical / diagonal
        patterns.
        """
        x, y, z = self.x, self.y, self.z
        planes = [(y, z), (x, z), (x, y)]
        if axis == "vertical":
            planes = [(z, y), (z, x), (y, x)]
        elif axis == "diagonal":
            r = F32(math.sqrt(0.5))
            planes = [((u - v) * r, (u + v) * r) for u, v in planes]
        return planes


def col(rgb: RGB) -> np.ndarray:
    """A constant colour as a ``(3, 1) float32`` column."""
    return np.asarray(rgb, dtype=F32).reshape(3, 1)


def lerp(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``a + (b - a) t`` with colours ``(3, n|1)`` and weights ``t (n,)`` -> ``(3, n)``."""
    return a + (b - a) * t


def smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    """Hermite step from 0 (x <= e0) to 1 (x >= e1), ``(n,) float32``."""
    t = (x - F32(e0)) * F32(1.0 / (e1 - e0))
    np.clip(t, F32(0.0), F32(1.0), out=t)
    return t * t * (F32(3.0) - F32(2.0) * t)


def luma(c: np.ndarray) -> np.ndarray:
    """Rec. 709 luma of ``(3, n)`` colours (gamma-encoded), ``(n,)``."""
    return F32(0.2126) * c[0] + F32(0.7152) * c[1] + F32(0.0722) * c[2]


def relative(spec: MaterialSpec, albedo: np.ndarray, strength: float = 1.0) -> np.ndarray:
    """The accent as a change of the main colour, applied to a per-point ``albedo`` (so the darker
    rings of wood follow the stripes under them). For a material's own colours the change is the
    per-channel ratio accent / main (wood rings get darker *and* redder); for colours from the prompt
    it is a plain darkening by 0.55. ``(3, n|1)``."""
    if spec.user_colors:
        ratio = np.full((3, 1), 0.55, dtype=F32)
    else:
        main = np.asarray(spec.base_color, dtype=F32)
        acc = np.asarray(spec.accent_color, dtype=F32)
        ratio = np.clip((acc + F32(0.02)) / (main + F32(0.02)), 0.15, 2.5).reshape(3, 1).astype(F32)
    return albedo * (F32(1.0) + (ratio - F32(1.0)) * F32(strength))


def sheen(ctx: Ctx, amount: float) -> np.ndarray:
    """A soft highlight on upward-facing surfaces (light from +z), ``(n,)``: mild and smooth in the normal."""
    return F32(amount) * smoothstep(0.3, 1.0, ctx.nz)
