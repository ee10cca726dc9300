"""Regions within a part, read from the prompt: "a dinner fork with a silver tip and a dark wood handle".

:func:`split_regions` cuts a prompt into clauses at commas, semicolons, colons, "with" (and "having",
"featuring"), and at "and" right after a clause that ends in a region word (or, after "with", in a
word the prompt parser does not know). A clause that ends in a
region word ("a silver tip", "red top", "a gold rim") -- or starts with one followed by "in", "of" or
"made of" ("handle in dark wood") -- describes that region; the other clauses are the rest of the
surface. Region words are, first, the labels of the shape's part groups ("handle" on a fork whose
handle is its own part, "legs" for the group "leg": that group gets the clause as its prompt), then
the regions of :data:`REGION_WORDS`:

========= ======================================================== ========================================
region    words                                                    where, in the scope's frame
========= ======================================================== ========================================
head      tip, point, head, blade, bowl, tines, prongs, nib         the wide end of the principal axis (35 %)
handle    handle, grip, stem, shaft, haft                           the narrow end (the other 65 %)
top       top, upper, lid, cap, crown, neck                         the upper 30 % along the up axis
bottom    bottom, base, foot, feet, lower, underside, sole          the lower 20 %
rim       rim, lip, brim, edge, mouth                               a band along an open surface's border; on
                                                                    a closed one the top 5 %
inside    inside, interior, inner, lining                           surface facing the scope's centre
outside   outside, exterior, outer                                  surface facing away from it
========= ======================================================== ========================================

Each region has a soft boundary (a smoothstep a few per cent of the scope wide). The *scope* is what the
prompt paints: the whole shape for the global prompt, the group's representative part for a group
prompt (or a clause routed to a group). "body" names the rest. A clause after "with" whose last word
is neither a region nor understood by the prompt parser ("with a gold spout") is an unknown region:
its words are not used and the notes say so.

:class:`RegionFrame` is the scope's geometry (principal axis oriented to the wide end, extents, border
points) in the shape's normalised frame; :func:`region_weight` is a pure function of a point, its
normal and the frame, so texels, pixels and chunks agree.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

__all__ = ["REGION_WORDS", "REGIONS", "RegionPlan", "RegionFrame", "split_regions", "region_weight"]

#: region -> (kind of rule, share of the scope it takes)
REGIONS: dict[str, tuple[str, float]] = {
    "head": ("axis", 0.35), "handle": ("axis", 0.65), "top": ("up", 0.3), "bottom": ("up", 0.2),
    "rim": ("rim", 0.05), "inside": ("facing", 0.0), "outside": ("facing", 0.0),
}  # fmt: skip

REGION_WORDS: dict[str, str] = {
    **{w: "head" for w in ("tip", "tips", "point", "points", "head", "blade", "bowl", "tines", "prongs", "nib")},
    **{w: "handle" for w in ("handle", "handles", "grip", "stem", "shaft", "haft")},
    **{w: "top" for w in ("top", "upper", "lid", "cap", "crown", "neck")},
    **{w: "bottom" for w in ("bottom", "base", "foot", "feet", "lower", "underside", "sole")},
    **{w: "rim" for w in ("rim", "lip", "brim", "edge", "edges", "mouth")},
    **{w: "inside" for w in ("inside", "interior", "inner", "lining")},
    **{w: "outside" for w in ("outside", "exterior", "outer")},
    "body": "rest",
}

_CUT = {",", ";", ":", "with", "having", "featuring"}
#: region clauses a prompt may hold (each is a material evaluated where its region lies); more are
#: dropped with a note, and a region named twice keeps its last clause
MAX_REGIONS = 8
_PREPOSITIONS = {"in", "of", "made"}
_ARTICLES = {"a", "an", "the", "its", "their"}
_SOFT = 0.04  # half-width of a region's soft boundary, as a share of the scope


@dataclass(frozen=True)
class RegionPlan:
    """A prompt split into the rest, regions and part clauses.

    Attributes:
        prompt: the prompt as given.
        base: the text for the rest of the surface (the whole prompt when it names no region).
        regions: ``(region, text)`` in prompt order, region one of :data:`REGIONS`.
        parts: ``(group label, text)``: clauses that name a part group of the shape.
        unknown: region words that are neither a group nor a known region (their text is unused).
        notes: human-readable lines on what was read.
        unplaced: the text of each unknown region's clause, in the order of ``unknown``
            (:mod:`.partwords` gives it to the rest when the rest names no material).
    """

    prompt: str
    base: str
    regions: tuple[tuple[str, str], ...] = ()
    parts: tuple[tuple[str, str], ...] = ()
    unknown: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    unplaced: tuple[str, ...] = ()

    @property
    def has_regions(self) -> bool:
        return bool(self.regions or self.parts or self.unknown)


def _label_of(word: str, labels: dict[str, str]) -> str | None:
    for cand in (word, word[:-1] if word.endswith("s") else "", word[:-2] if word.endswith("es") else ""):
        if cand and cand in labels:
            return labels[cand]
    return None


def _unknown_noun(word: str) -> bool:
    """A word the prompt parser does not know (a part name it cannot place, "spout"): after "with",
    an "and" following it starts a new clause ("a gold spout and dark walnut legs")."""
    from .prompt import parse_prompt

    return word in parse_prompt(word).ignored


def split_regions(prompt: str, labels: Iterable[str] = ()) -> RegionPlan:
    """Split ``prompt`` into its rest, region clauses and part clauses (module docstring).

    Args:
        prompt: any string (``ValueError`` for a non-string).
        labels: the shape's group labels; a clause naming one is routed to that group.
    Returns:
        :class:`RegionPlan`; a prompt without region words gives ``base == prompt`` unchanged.
    """
    from .prompt import parse_prompt

    if not isinstance(prompt, str):
        raise ValueError(f"prompt must be a string, got {type(prompt).__name__}")
    label_map = {str(lab).lower(): str(lab) for lab in labels if lab}
    tokens = re.findall(r"#[0-9a-fA-F]{3,6}\b|[\w'-]+|[,;:]", prompt.lower())

    def region_of(word: str) -> tuple[str, str] | None:
        lab = _label_of(word, label_map)
        if lab is not None:
            return "part", lab
        if word in REGION_WORDS:
            return "region", REGION_WORDS[word]
        return None

    segments: list[tuple[list[str], bool]] = []  # (words, came after "with" / a region clause)
    cur: list[str] = []
    after = False
    for tok in tokens:
        if tok in _CUT or (tok == "and" and cur and (region_of(cur[-1]) or (after and _unknown_noun(cur[-1])))):
            if cur:
                segments.append((cur, after))
            after = after or tok in ("with", "having", "featuring", "and")
            cur = []
            continue
        cur.append(tok)
    if cur:
        segments.append((cur, after))

    base: list[str] = []
    regions: list[tuple[str, str]] = []
    parts: list[tuple[str, str]] = []
    unknown: list[str] = []
    unplaced: list[str] = []
    notes: list[str] = []
    for words, after_with in segments:
        words = [w for w in words if w not in _ARTICLES] or words
        target, text = None, ""
        if region_of(words[-1]):
            target, text = region_of(words[-1]), " ".join(words[:-1])
        elif len(words) > 2 and region_of(words[0]) and words[1] in _PREPOSITIONS:
            rest = words[2:]
            if rest and rest[0] == "of" and words[1] == "made":
                rest = rest[1:]
            target, text = region_of(words[0]), " ".join(rest)
        if target is None:
            if after_with and len(words) > 1 and words[-1] in parse_prompt(" ".join(words)).ignored:
                unknown.append(words[-1])
                unplaced.append(" ".join(words[:-1]))
                notes.append(f"region {words[-1]!r} is neither a part of this shape nor a region ProcTex knows ({', '.join(r for r in REGIONS)}); {' '.join(words[:-1])!r} was not used")
            else:
                base.append(" ".join(words))
            continue
        kind, name = target
        if not text:
            notes.append(f"{words[-1]!r} names no material; ignored")
            continue
        if kind == "part":
            parts.append((name, text))
            notes.append(f"part {name!r}: {text!r}")
        elif name == "rest":
            base.append(text)
        else:
            regions.append((name, text))
            notes.append(f"region {name}: {text!r}")
    if not (regions or parts or unknown):
        return RegionPlan(prompt, prompt, notes=tuple(notes))
    last = {name: text for name, text in regions}  # a region named twice: its last clause
    if len(last) < len(regions):
        notes.append(f"{len(regions) - len(last)} region clause(s) named a region again; the last one is used")
    regions = [(name, last[name]) for name in dict.fromkeys(name for name, _ in regions)]
    if len(regions) > MAX_REGIONS:
        notes.append(f"{len(regions)} regions named; the first {MAX_REGIONS} are used")
        regions = regions[:MAX_REGIONS]
    return RegionPlan(prompt, " ".join(base), tuple(regions), tuple(parts), tuple(unknown), tuple(notes), tuple(unplaced))


# ----------------------------------------------------------------------------------------- geometry
@dataclass
class RegionFrame:
    """Where the regions of one scope lie, in the shape's normalised frame.

    Attributes:
        center: (3,) area centroid; axis: (3,) unit principal axis pointing to the wide end;
        axis_range: (lo, hi) of ``(p - center) . axis`` over the scope; up: index of the up axis
        (0, 1, 2); up_range: (lo, hi) of that coordinate; border: (k, 3) points along the open
        border (empty for a closed surface); size: the scope's bounding-box diagonal.
    """

    center: np.ndarray
    axis: np.ndarray
    axis_range: tuple[float, float]
    up: int
    up_range: tuple[float, float]
    border: np.ndarray
    size: float
    _tree: object = field(default=None, repr=False)

    @classmethod
    def from_mesh(cls, vertices: np.ndarray, faces: np.ndarray, up: int = 2) -> "RegionFrame":
        """The frame of a scope mesh ``vertices (n, 3)`` (normalised frame), ``faces (m, 3)``."""
        v = np.asarray(vertices, dtype=np.float64)
        f = np.asarray(faces, dtype=np.int64)
        if len(f) == 0 or not np.isfinite(v).all():
            raise ValueError("a region frame needs a non-empty, finite mesh")
        tri = v[f]
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        cent = tri.mean(axis=1)
        w = area / area.sum() if area.sum() > 0 else np.full(len(f), 1.0 / len(f))
        center = (cent * w[:, None]).sum(0)
        d = cent - center
        cov = (d * w[:, None]).T @ d
        evals, evecs = np.linalg.eigh(cov)
        axis = evecs[:, -1]
        used = np.unique(f)
        s = (v[used] - center) @ axis
        lo, hi = float(s.min()), float(s.max())
        # Orient the axis to the wide end: the end slab whose points lie further from the axis.
        span = max(hi - lo, 1e-12)
        radial = np.linalg.norm((v[used] - center) - np.outer(s, axis), axis=1)
        near_hi, near_lo = s > hi - 0.15 * span, s < lo + 0.15 * span
        spread_hi = radial[near_hi].mean() if near_hi.any() else 0.0
        spread_lo = radial[near_lo].mean() if near_lo.any() else 0.0
        if spread_lo > spread_hi * 1.05 or (abs(spread_lo - spread_hi) <= 0.05 * max(spread_hi, 1e-12) and axis[np.argmax(np.abs(axis))] < 0):
            axis, lo, hi = -axis, -hi, -lo
        # The open border: edges used by one face only, sampled densely.
        e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        uniq, counts = np.unique(e, axis=0, return_counts=True)
        border_edges = uniq[counts == 1]
        pts = [v[border_edges[:, 0]] * (1 - t) + v[border_edges[:, 1]] * t for t in np.linspace(0.0, 1.0, 5)] if len(border_edges) else []
        border = np.concatenate(pts) if pts else np.zeros((0, 3))
        size = float(np.linalg.norm(v[used].max(0) - v[used].min(0)))
        z = v[used][:, up]
        return cls(center, axis, (lo, hi), up, (float(z.min()), float(z.max())), border, max(size, 1e-12))

    def border_distance(self, points: np.ndarray) -> np.ndarray:
        """(n,) distance from each point to the open border (inf without one)."""
        if len(self.border) == 0:
            return np.full(len(points), np.inf)
        if self._tree is None:
            from scipy.spatial import cKDTree

            self._tree = cKDTree(self.border)
        return self._tree.query(points)[0]


def _smooth(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def region_weight(region: str, frame: RegionFrame, points: np.ndarray, normals: np.ndarray, named: Iterable[str] = ()) -> np.ndarray:
    """How much each point belongs to ``region``: ``(n,) float64`` in [0, 1].

    ``points``, ``normals``: (n, 3) in the shape's normalised frame. ``named``: every region the prompt
    names; when both ends of one axis are named ("tip" and "handle", "top" and "bottom"), they meet at
    the same boundary instead of leaving a gap. ``ValueError`` for an unknown region.
    """
    if region not in REGIONS:
        raise ValueError(f"unknown region {region!r}; regions are {', '.join(REGIONS)}")
    p = np.asarray(points, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    kind, share = REGIONS[region]
    named = set(named)
    if kind == "axis":
        lo, hi = frame.axis_range
        s = ((p - frame.center) @ frame.axis - lo) / max(hi - lo, 1e-12)  # 1 at the wide end
        cut = 1.0 - REGIONS["head"][1]  # tip and handle always meet at the same place
        w = _smooth(cut - _SOFT, cut + _SOFT, s)
        return w if region == "head" else 1.0 - w
    if kind == "up":
        lo, hi = frame.up_range
        t = (p[:, frame.up] - lo) / max(hi - lo, 1e-12)
        top, bottom = REGIONS["top"][1], REGIONS["bottom"][1]
        if {"top", "bottom"} <= named:  # meet halfway between their own boundaries
            cut = 0.5 * ((1.0 - REGIONS["top"][1]) + REGIONS["bottom"][1])
            w = _smooth(cut - _SOFT, cut + _SOFT, t)
            return w if region == "top" else 1.0 - w
        if region == "top":
            return _smooth(1.0 - top - _SOFT, 1.0 - top + _SOFT, t)
        return 1.0 - _smooth(bottom - _SOFT, bottom + _SOFT, t)
    if kind == "rim":
        if len(frame.border):
            width = share * frame.size
            return 1.0 - _smooth(0.6 * width, 1.4 * width, frame.border_distance(p))
        lo, hi = frame.up_range
        t = (p[:, frame.up] - lo) / max(hi - lo, 1e-12)
        return _smooth(1.0 - share - 0.01, 1.0 - share + 0.01, t)
    # facing: inside where the normal points towards the scope's centre
    d = p - frame.center
    length = np.linalg.norm(d, axis=1)
    cos = -(n * d).sum(1) / np.maximum(length, 1e-12)
    w = _smooth(0.02, 0.2, cos)
    return w if region == "inside" else 1.0 - w
