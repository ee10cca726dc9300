"""A corpus of multi-part objects with known part roles, for the part-word benchmark (issue 51).

Written for the benchmark only: the resolver (:mod:`proctex.texture.painters.partwords`) never
imports it, and its shapes reach the resolver without their labels. Each object is one of 21
builders in 8 kinds (furniture, beds, lighting, tableware, vehicles, buildings, plants, tools),
drawn with its own random sizes, part counts and optional parts, then turned about the up axis by a
quarter turn, possibly mirrored, scaled by 10^U(-2, 2) and moved. Every part carries its role (a
*truth word*: "legs", "headboard", "shade", ...) as its label; :func:`make_object` returns the shape
with the labels and :func:`unlabelled` the copy the resolver sees.

Seeds: ``partcorpus_seeds.json`` beside this file holds the development seeds and the held-out
seeds (drawn once, at random, when the corpus was written and before the resolver was changed).
Held-out objects are for the final figures only: no threshold, word or rule is tuned on them.

``python tests/bench/partcorpus.py [--split development|held_out] [--n N]`` prints a summary.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from proctex.geometry import primitives as P
from proctex.geometry import sweeps as S
from proctex.geometry.shape import Shape, ShapeBuilder

SEEDS = Path(__file__).with_name("partcorpus_seeds.json")

#: truth word -> the forms a user writes for it (the benchmark's prompts draw from these; the
#: resolver's own vocabulary is separate and may know more or fewer)
FORMS: dict[str, tuple[str, ...]] = {
    "legs": ("legs", "leg", "feet"),
    "seat": ("seat",),
    "back": ("back", "backrest"),
    "arms": ("arms", "armrests"),
    "rungs": ("rungs", "stretchers"),
    "top": ("top", "tabletop", "table top"),
    "apron": ("apron", "rails"),
    "drawers": ("drawers", "drawer fronts"),
    "doors": ("doors", "door"),
    "handles": ("handles", "knobs", "pulls"),
    "body": ("body",),
    "base": ("base", "plinth", "stand"),
    "cushions": ("cushions", "seat cushions"),
    "mattress": ("mattress",),
    "headboard": ("headboard",),
    "footboard": ("footboard",),
    "frame": ("frame", "bed frame", "side rails"),
    "pillows": ("pillows", "pillow"),
    "pole": ("pole", "stem"),
    "shade": ("shade", "lampshade"),
    "arm": ("arm",),
    "handle": ("handle",),
    "spout": ("spout",),
    "lid": ("lid",),
    "cup": ("cup", "bowl"),
    "stem": ("stem",),
    "foot": ("foot",),
    "cabin": ("cabin", "cab"),
    "wheels": ("wheels", "tyres", "tires"),
    "bumpers": ("bumpers",),
    "walls": ("walls",),
    "roof": ("roof",),
    "door": ("door",),
    "windows": ("windows",),
    "chimney": ("chimney",),
    "trunk": ("trunk",),
    "canopy": ("leaves", "canopy", "foliage"),
    "branches": ("branches",),
    "pot": ("pot", "planter"),
    "cap": ("cap",),
    "head": ("head",),
    "blade": ("blade",),
    "shaft": ("shaft", "handle"),
}

Parts = list[tuple[P.Part, str]]


def _box(lo, hi, div: int = 2) -> P.Part:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return P.box(hi - lo, (lo + hi) / 2, (div, div, div))


def _rod(a, b, r: float, sides: int = 10) -> P.Part:
    """A closed round rod from point ``a`` to ``b``."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    d = (b - a) / np.linalg.norm(b - a)
    up = (0.0, 0.0, 1.0) if abs(d[2]) < 0.9 else (1.0, 0.0, 0.0)
    return S.tube(np.array([a, (a + b) / 2, b]), r, n_sides=sides, up=up)


def _frustum(r0: float, r1: float, z0: float, z1: float, xy=(0.0, 0.0), n: int = 20) -> P.Part:
    """A closed cone frustum about a vertical axis (radii > 0)."""
    return S.revolve(np.array([r0, (r0 + r1) / 2, r1]), np.array([z0, (z0 + z1) / 2, z1]), n_theta=n, center=(xy[0], xy[1], 0.0))


def _ball(c, r: float, squash: float = 1.0, n: int = 16) -> P.Part:
    t = np.linspace(0.15, np.pi - 0.15, 7)
    part = S.revolve(r * np.sin(t), -r * squash * np.cos(t), n_theta=n, z_bottom=-r * squash, z_top=r * squash)
    return P.transform(part, t=c)


def _legs(xs, ys, z0: float, z1: float, w: float, round_: bool) -> Parts:
    out = []
    for x in xs:
        for y in ys:
            out.append((_rod((x, y, z0), (x, y, z1), w / 2) if round_ else _box((x - w / 2, y - w / 2, z0), (x + w / 2, y + w / 2, z1)), "legs"))
    return out


# --------------------------------------------------------------------------------------- furniture
def chair(rng) -> tuple[str, Parts]:
    w, d, sh = rng.uniform(0.4, 0.6), rng.uniform(0.4, 0.55), rng.uniform(0.4, 0.5)
    t, lw, bh = rng.uniform(0.03, 0.07), rng.uniform(0.03, 0.05), rng.uniform(0.35, 0.6)
    round_ = rng.random() < 0.5
    parts = _legs((-w / 2 + lw, w / 2 - lw), (-d / 2 + lw, d / 2 - lw), 0, sh - t, lw, round_)
    parts.append((_box((-w / 2, -d / 2, sh - t), (w / 2, d / 2, sh)), "seat"))
    parts.append((_box((-w / 2, d / 2 - 0.04, sh), (w / 2, d / 2, sh + bh)), "back"))
    if rng.random() < 0.5:
        for s in (-1, 1):
            parts.append((_box((s * w / 2 - 0.025, -d / 2, sh + 0.18), (s * w / 2 + 0.025, d / 2 - 0.05, sh + 0.22)), "arms"))
    if rng.random() < 0.4:
        for s in (-1, 1):
            parts.append((_box((s * (w / 2 - lw) - 0.01, -d / 2 + lw, 0.12), (s * (w / 2 - lw) + 0.01, d / 2 - lw, 0.14)), "rungs"))
    return "chair", parts


def table(rng) -> tuple[str, Parts]:
    w, d, h = rng.uniform(0.8, 1.8), rng.uniform(0.6, 1.0), rng.uniform(0.7, 0.78)
    t, lw = rng.uniform(0.03, 0.06), rng.uniform(0.04, 0.08)
    parts = _legs((-w / 2 + lw, w / 2 - lw), (-d / 2 + lw, d / 2 - lw), 0, h - t, lw, rng.random() < 0.5)
    parts.append((_box((-w / 2, -d / 2, h - t), (w / 2, d / 2, h)), "top"))
    if rng.random() < 0.5:
        for s in (-1, 1):
            parts.append((_box((-w / 2 + 2 * lw, s * (d / 2 - lw) - 0.01, h - t - 0.1), (w / 2 - 2 * lw, s * (d / 2 - lw) + 0.01, h - t)), "apron"))
    if rng.random() < 0.3:
        parts.append((_box((-0.2, -d / 2 - 0.005, h - t - 0.1), (0.2, -d / 2 + 0.3, h - t - 0.01)), "drawers"))
    return "table", parts


def sofa(rng) -> tuple[str, Parts]:
    w, d, n = rng.uniform(1.4, 2.4), rng.uniform(0.8, 1.0), int(rng.integers(2, 4))
    lh, bz, aw = rng.uniform(0.06, 0.15), rng.uniform(0.15, 0.25), rng.uniform(0.12, 0.25)
    parts = _legs((-w / 2 + 0.05, w / 2 - 0.05), (-d / 2 + 0.05, d / 2 - 0.05), 0, lh, 0.05, rng.random() < 0.5)
    parts.append((_box((-w / 2, -d / 2, lh), (w / 2, d / 2, lh + bz)), "base"))
    inner = w - 2 * aw
    for i in range(n):
        x0 = -inner / 2 + i * inner / n
        parts.append((_box((x0 + 0.01, -d / 2, lh + bz), (x0 + inner / n - 0.01, d / 2 - 0.2, lh + bz + 0.15)), "cushions"))
    parts.append((_box((-inner / 2, d / 2 - 0.2, lh + bz), (inner / 2, d / 2, lh + bz + rng.uniform(0.4, 0.55))), "back"))
    for s in (-1, 1):
        parts.append((_box((s * (w / 2 - aw / 2) - aw / 2, -d / 2, lh + bz), (s * (w / 2 - aw / 2) + aw / 2, d / 2, lh + bz + rng.uniform(0.2, 0.3))), "arms"))
    return "sofa", parts


def cabinet(rng) -> tuple[str, Parts]:
    w, d, h = rng.uniform(0.5, 1.2), rng.uniform(0.35, 0.6), rng.uniform(0.7, 1.9)
    on_legs = rng.random() < 0.5
    z0 = rng.uniform(0.1, 0.2) if on_legs else 0.08
    parts = _legs((-w / 2 + 0.04, w / 2 - 0.04), (-d / 2 + 0.04, d / 2 - 0.04), 0, z0, 0.04, True) if on_legs else [(_box((-w / 2 + 0.03, -d / 2 + 0.03, 0), (w / 2 - 0.03, d / 2 - 0.03, z0)), "base")]
    parts.append((_box((-w / 2, -d / 2 + 0.02, z0), (w / 2, d / 2, h - 0.03)), "body"))
    parts.append((_box((-w / 2 - 0.02, -d / 2, h - 0.03), (w / 2 + 0.02, d / 2 + 0.02, h)), "top"))
    nd = int(rng.integers(1, 3))
    dz = z0 + (h - z0) * (0.3 if rng.random() < 0.5 else 0.0)
    for i in range(nd):
        x0 = -w / 2 + i * w / nd
        parts.append((_box((x0 + 0.005, -d / 2, dz + 0.01), (x0 + w / nd - 0.005, -d / 2 + 0.02, h - 0.04)), "doors"))
        hx = x0 + w / nd - 0.06 if i == 0 else x0 + 0.06
        parts.append((_box((hx - 0.01, -d / 2 - 0.03, (dz + h) / 2 - 0.06), (hx + 0.01, -d / 2, (dz + h) / 2 + 0.06)), "handles"))
    if dz > z0 + 0.05:
        parts.append((_box((-w / 2 + 0.005, -d / 2, z0 + 0.01), (w / 2 - 0.005, -d / 2 + 0.02, dz - 0.005)), "drawers"))
    return "cabinet", parts


def desk(rng) -> tuple[str, Parts]:
    w, d, h = rng.uniform(1.0, 1.6), rng.uniform(0.55, 0.8), rng.uniform(0.72, 0.78)
    parts: Parts = [(_box((-w / 2, -d / 2, h - 0.03), (w / 2, d / 2, h)), "top")]
    if rng.random() < 0.5:
        parts += _legs((-w / 2 + 0.04, w / 2 - 0.04), (-d / 2 + 0.04, d / 2 - 0.04), 0, h - 0.03, 0.05, False)
    else:
        for s in (-1, 1):
            parts.append((_box((s * (w / 2 - 0.02) - 0.02, -d / 2 + 0.02, 0), (s * (w / 2 - 0.02) + 0.02, d / 2 - 0.02, h - 0.03)), "legs"))
    for i in range(int(rng.integers(1, 4))):
        z1 = h - 0.04 - i * 0.14
        parts.append((_box((w / 2 - 0.5, -d / 2, z1 - 0.12), (w / 2 - 0.08, -d / 2 + 0.4, z1)), "drawers"))
    return "desk", parts


# -------------------------------------------------------------------------------------------- beds
def bed(rng) -> tuple[str, Parts]:
    w, L, fz = rng.uniform(0.9, 1.8), rng.uniform(1.9, 2.1), rng.uniform(0.15, 0.3)
    parts = _legs((-w / 2 + 0.04, w / 2 - 0.04), (-L / 2 + 0.04, L / 2 - 0.04), 0, fz, 0.06, rng.random() < 0.5)
    parts.append((_box((-w / 2, -L / 2, fz), (w / 2, L / 2, fz + 0.12)), "frame"))
    mz = fz + 0.12 + rng.uniform(0.15, 0.28)
    parts.append((_box((-w / 2 + 0.03, -L / 2 + 0.03, fz + 0.12), (w / 2 - 0.03, L / 2 - 0.03, mz)), "mattress"))
    parts.append((_box((-w / 2, L / 2, 0), (w / 2, L / 2 + 0.05, mz + rng.uniform(0.4, 0.8))), "headboard"))
    if rng.random() < 0.6:
        parts.append((_box((-w / 2, -L / 2 - 0.05, 0), (w / 2, -L / 2, mz + rng.uniform(0.0, 0.2))), "footboard"))
    if rng.random() < 0.7:
        n = 1 if w < 1.2 else 2
        for i in range(n):
            x0 = -w / 2 + 0.08 + i * (w - 0.16) / n
            parts.append((_box((x0, L / 2 - 0.5, mz), (x0 + (w - 0.16) / n - 0.04, L / 2 - 0.1, mz + 0.12)), "pillows"))
    return "bed", parts


# ---------------------------------------------------------------------------------------- lighting
def floor_lamp(rng) -> tuple[str, Parts]:
    h, r = rng.uniform(1.3, 1.8), rng.uniform(0.15, 0.25)
    sr, sh = rng.uniform(0.18, 0.3), rng.uniform(0.2, 0.35)
    return "lamp", [(_frustum(r, r * 0.9, 0, 0.04), "base"), (_rod((0, 0, 0.04), (0, 0, h - sh * 0.8), 0.015), "pole"), (_frustum(sr, sr * rng.uniform(0.55, 0.8), h - sh, h), "shade")]


def desk_lamp(rng) -> tuple[str, Parts]:
    r, a1, a2 = rng.uniform(0.08, 0.12), rng.uniform(0.25, 0.4), rng.uniform(0.2, 0.35)
    top = np.array([0.05, 0.0, a1])
    tip = top + np.array([a2, 0.0, 0.05])
    parts: Parts = [(_frustum(r, r * 0.9, 0, 0.03), "base"), (_rod((0, 0, 0.03), top, 0.012), "arm"), (_rod(top, tip, 0.012), "arm")]
    parts.append((_frustum(0.09, 0.04, tip[2] - 0.12, tip[2] - 0.01, xy=(tip[0] + 0.02, 0)), "shade"))
    return "lamp", parts


def table_lamp(rng) -> tuple[str, Parts]:
    bh, _br = rng.uniform(0.2, 0.35), rng.uniform(0.06, 0.1)  # _br: drawn, so the stream stays the corpus's
    sr = rng.uniform(0.14, 0.22)
    return "lamp", [(_ball((0, 0, bh / 2), bh / 2, squash=1.0), "base"), (_rod((0, 0, bh), (0, 0, bh + 0.12), 0.01), "pole"), (_frustum(sr, sr * 0.65, bh + 0.08, bh + 0.08 + sr * 1.2), "shade")]


# --------------------------------------------------------------------------------------- tableware
def mug(rng) -> tuple[str, Parts]:
    r, h = rng.uniform(0.035, 0.05), rng.uniform(0.08, 0.12)
    body = _frustum(r, r * rng.uniform(1.0, 1.15), 0, h)
    handle = S.tube(np.array([[r * 0.9, 0, h * 0.75], [r + 0.03, 0, h * 0.5], [r * 0.9, 0, h * 0.25]]), 0.006, n_sides=10, up=(0.0, 1.0, 0.0))
    return "mug", [(body, "body"), (handle, "handle")]


def teapot(rng) -> tuple[str, Parts]:
    r = rng.uniform(0.08, 0.12)
    parts: Parts = [(_ball((0, 0, r * 0.8), r, squash=0.8), "body"), (_frustum(r * 0.4, r * 0.15, r * 1.45, r * 1.65), "lid")]
    parts.append((_rod((r * 0.8, 0, r * 0.6), (r * 1.6, 0, r * 1.3), r * 0.1), "spout"))
    parts.append((_rod((-r * 0.9, 0, r * 1.2), (-r * 1.45, 0, r * 0.6), r * 0.06), "handle"))
    return "teapot", parts


def goblet(rng) -> tuple[str, Parts]:
    r, sh = rng.uniform(0.035, 0.05), rng.uniform(0.06, 0.1)
    return "goblet", [(_frustum(r * 1.2, r * 1.1, 0, 0.01), "foot"), (_rod((0, 0, 0.01), (0, 0, 0.01 + sh), 0.005), "stem"), (_frustum(r * 0.5, r, 0.01 + sh, 0.01 + sh + r * 2), "cup")]


# ---------------------------------------------------------------------------------------- vehicles
def car(rng) -> tuple[str, Parts]:
    L, w, wr = rng.uniform(3.5, 4.8), rng.uniform(1.6, 1.9), rng.uniform(0.3, 0.36)
    parts: Parts = [(_box((-w / 2, -L / 2, wr * 0.6), (w / 2, L / 2, wr * 0.6 + rng.uniform(0.55, 0.75))), "body")]
    top = parts[0][0].vertices[:, 2].max()
    parts.append((_box((-w / 2 + 0.1, -L * 0.15, top), (w / 2 - 0.1, L * 0.25, top + rng.uniform(0.4, 0.55))), "cabin"))
    for x in (-w / 2 - 0.1, w / 2 - 0.1):
        for y in (-L * 0.32, L * 0.32):
            parts.append((_rod((x, y, wr), (x + 0.2, y, wr), wr, sides=16), "wheels"))
    if rng.random() < 0.5:
        for s in (-1, 1):
            parts.append((_box((-w / 2, s * L / 2 - 0.06, wr * 0.6), (w / 2, s * L / 2 + 0.06, wr * 0.6 + 0.15)), "bumpers"))
    return "car", parts


def truck(rng) -> tuple[str, Parts]:
    L, w, wr = rng.uniform(5, 7), rng.uniform(2.0, 2.5), rng.uniform(0.4, 0.5)
    z = wr * 0.8
    parts: Parts = [(_box((-w / 2, -L / 2, z), (w / 2, L / 2 - 1.8, z + rng.uniform(1.5, 2.5))), "body"), (_box((-w / 2, L / 2 - 1.7, z), (w / 2, L / 2, z + rng.uniform(1.4, 1.8))), "cabin")]
    axles = (-L * 0.35, -L * 0.1, L * 0.35) if rng.random() < 0.5 else (-L * 0.3, L * 0.35)
    for x in (-w / 2 - 0.12, w / 2 - 0.12):
        for y in axles:
            parts.append((_rod((x, y, wr), (x + 0.24, y, wr), wr, sides=16), "wheels"))
    return "truck", parts


# --------------------------------------------------------------------------------------- buildings
def _prism_roof(lo, hi, peak: float) -> P.Part:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)

    def warp(local, canon):
        out = local.copy()
        out[:, 0] *= 1.0 - 0.92 * canon[:, 2]
        return out

    return P.box(hi - lo, (lo + hi) / 2, (2, 2, 2), warp=warp) if peak else _box(lo, hi)


def house(rng) -> tuple[str, Parts]:
    w, d, h = rng.uniform(6, 12), rng.uniform(6, 10), rng.uniform(2.6, 6.0)
    rh = rng.uniform(1.5, 3.5)
    parts: Parts = [
        (_box((-w / 2, -d / 2, 0), (w / 2, d / 2, h)), "walls"),
        (_prism_roof((-w / 2 - 0.3, -d / 2 - 0.3, h), (w / 2 + 0.3, d / 2 + 0.3, h + rh), rh), "roof"),
        (_box((-0.5, -d / 2 - 0.08, 0), (0.5, -d / 2, 2.1)), "door"),
    ]
    nw = int(rng.integers(2, 5))
    for i in range(nw):
        x = -w / 2 + (i + 0.5) * w / nw
        if abs(x) < 0.9:
            x += 1.2
        parts.append((_box((x - 0.5, -d / 2 - 0.06, h * 0.45), (x + 0.5, -d / 2, h * 0.45 + 1.1)), "windows"))
    if rng.random() < 0.6:
        cx = rng.uniform(-w / 4, w / 4)
        parts.append((_box((cx - 0.3, d / 6 - 0.3, h + rh * 0.3), (cx + 0.3, d / 6 + 0.3, h + rh + 0.8)), "chimney"))
    return "house", parts


# ------------------------------------------------------------------------------------------ plants
def tree(rng) -> tuple[str, Parts]:
    h, r = rng.uniform(2, 6), rng.uniform(0.1, 0.3)
    parts: Parts = [(_frustum(r, r * 0.6, 0, h), "trunk")]
    for i in range(int(rng.integers(1, 4))):
        off = rng.uniform(-1, 1, 3) * np.array([0.4, 0.4, 0.2]) * h / 3
        parts.append((_ball(np.array([0, 0, h]) + off, h * rng.uniform(0.25, 0.4), squash=rng.uniform(0.7, 1.0)), "canopy"))
    if rng.random() < 0.5:
        for s in (-1, 1):
            parts.append((_rod((0, 0, h * 0.55), (s * h * 0.3, 0, h * 0.8), r * 0.3), "branches"))
    return "tree", parts


def potted_plant(rng) -> tuple[str, Parts]:
    pr, ph = rng.uniform(0.1, 0.2), rng.uniform(0.15, 0.3)
    parts: Parts = [(_frustum(pr * 0.75, pr, 0, ph), "pot"), (_rod((0, 0, ph), (0, 0, ph + rng.uniform(0.2, 0.5)), 0.008), "stem")]
    top = ph + 0.2
    for i in range(int(rng.integers(2, 6))):
        a = 2 * np.pi * i / 5 + rng.uniform(0, 0.5)
        c = np.array([np.cos(a) * 0.12, np.sin(a) * 0.12, top + rng.uniform(0, 0.2)])
        parts.append((_ball(c, 0.08, squash=0.25, n=12), "canopy"))
    return "plant", parts


def mushroom(rng) -> tuple[str, Parts]:
    sh, sr = rng.uniform(0.05, 0.12), rng.uniform(0.01, 0.025)
    cr = rng.uniform(0.04, 0.09)
    return "mushroom", [(_frustum(sr * 1.2, sr, 0, sh), "stem"), (_ball((0, 0, sh), cr, squash=rng.uniform(0.4, 0.7)), "cap")]


# ------------------------------------------------------------------------------------------- tools
def hammer(rng) -> tuple[str, Parts]:
    L = rng.uniform(0.25, 0.4)
    return "hammer", [(_rod((0, 0, 0), (0, 0, L), rng.uniform(0.012, 0.018)), "shaft"), (_box((-0.06, -0.015, L), (0.06, 0.015, L + 0.035)), "head")]


def shovel(rng) -> tuple[str, Parts]:
    L = rng.uniform(0.9, 1.3)
    return "shovel", [(_rod((0, 0, 0.28), (0, 0, 0.28 + L), 0.018), "shaft"), (_box((-0.12, -0.01, 0), (0.12, 0.01, 0.3)), "blade")]


def axe(rng) -> tuple[str, Parts]:
    L = rng.uniform(0.4, 0.8)
    return "axe", [(_rod((0, 0, 0), (0, 0, L), 0.02), "shaft"), (_box((0.0, -0.012, L - 0.14), (0.16, 0.012, L)), "head")]


KINDS: dict[str, tuple[Callable, ...]] = {
    "furniture": (chair, table, sofa, cabinet, desk),
    "beds": (bed,),
    "lighting": (floor_lamp, desk_lamp, table_lamp),
    "tableware": (mug, teapot, goblet),
    "vehicles": (car, truck),
    "buildings": (house,),
    "plants": (tree, potted_plant, mushroom),
    "tools": (hammer, shovel, axe),
}


@dataclass
class CorpusObject:
    """One object of the corpus.

    Attributes:
        seed: its seed; kind: its kind of object ("beds"); noun: what it is ("bed").
        shape: the shape with every part labelled by its truth word (``label_names`` are truth words).
        up: its up axis (the corpus: "z").
    """

    seed: int
    kind: str
    noun: str
    shape: Shape
    up: str = "z"


def make_object(seed: int) -> CorpusObject:
    """The object of ``seed`` (deterministic): a kind, then a builder of it, then sizes, parts and a
    placement (a quarter turn about z, a mirror, a scale of 10^U(-2, 2), a move)."""
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    rng = np.random.default_rng([51, int(seed)])
    kind = list(KINDS)[int(rng.integers(len(KINDS)))]
    builder = KINDS[kind][int(rng.integers(len(KINDS[kind])))]
    noun, parts = builder(rng)
    R = P.rotation("z", np.pi / 2 * int(rng.integers(4)))
    mirror = rng.random() < 0.5
    scale = 10.0 ** rng.uniform(-2, 2)
    move = rng.uniform(-5, 5, 3) * scale
    sb = ShapeBuilder()
    for part, role in parts:
        p = P.transform(part, R=R, t=move, scale=scale)
        sb.add(P.mirror(p, 0, move[0]) if mirror else p, role)
    return CorpusObject(int(seed), kind, noun, sb.build(source=f"partcorpus:{seed}"))


def unlabelled(shape: Shape) -> Shape:
    """The copy the resolver sees: geometry only (no labels, canonical coordinates or parameters)."""
    return Shape(shape.vertices.copy(), shape.faces.copy(), source="partcorpus")


def seeds(split: str) -> list[int]:
    """The committed seeds of ``split`` ("development" or "held_out")."""
    data = json.loads(SEEDS.read_text())
    if split not in data:
        raise ValueError(f"split must be one of {', '.join(data)}, got {split!r}")
    return [int(s) for s in data[split]]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--split", default="development", choices=("development", "held_out"))
    ap.add_argument("--n", type=int, default=20)
    args = ap.parse_args(argv)
    for s in seeds(args.split)[: args.n]:
        o = make_object(s)
        roles = {}
        for lab in o.shape.labels:
            roles[o.shape.label_names[lab]] = roles.get(o.shape.label_names[lab], 0) + 1
        print(s, o.kind, o.noun, len(o.shape.vertices), "vertices:", ", ".join(roles))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
