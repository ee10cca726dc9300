"""Part words grounded in geometry: "a chair with a red velvet seat and dark walnut legs" on a mesh
whose parts carry no names.

Real exports (Blender, OBJ folders) name no parts, so a prompt's part nouns match no label. Here each
part word has a geometric test over the part groups of the shape, in its own up frame (the shape's
bounding box taken to [0, 1] per axis; sizes relative to the shape): what a seat, legs or a back
*are* in furniture and objects of every family, not in one generator. One table (:data:`PART_WORDS`)
serves every painter: :func:`plan_parts` resolves the words of a prompt to groups, splits the prompt
into the clauses that name them (:func:`proctex.texture.painters.regions.split_regions`), and gives
every group its text:

- a group a word took gets that word's clause ("red velvet" for the seat);
- a group no word took that passes the test of a word of the same kind as a word the prompt placed
  (:data:`KINDRED`: a chair's disc base or stretchers when the prompt names its legs) gets that
  word's clause;
- any other group no word took gets the rest of the prompt when the rest names a material ("an oak chair
  with a red velvet seat": oak), else the clause of the taken group most alike in shape (a back panel
  is a slab like the seat, arms are bars like the legs), so no group falls back to a plain default
  while the prompt names a material;
- a clause whose word no group passes (a "spout" on a chair) gives its material to the rest when the
  rest names none.

The notes say which groups each word took and why. Labels, where a shape has them, come first: a
word that names a group's label is routed by the label (as :mod:`.regions` always did), and so is a
word naming one word of a label of several words (a ``.blend`` node tree's "Left Arm" for "arms",
:func:`label_hits`); a group named by its label is not taken by a word's geometric test.

========== ==================================================================================
word       test (u: height in the shape, 0 floor, 1 top; sizes of one member)
========== ==================================================================================
legs       touch the floor (u_lo <= 0.1; or the top of a flat base on it), below the top part
           (u_hi <= 0.6) or an upright bar narrow across the shape (<= 30 % of its width and
           depth); not a slab covering most of the footprint
seat       a horizontal slab (thickness <= half its width) over >= 25 % of the footprint off the
           floor (u_mid >= 0.2) with no large slab above it: the largest such (at the very top,
           u_hi >= 0.9, it scores below "top")
top        a horizontal slab over >= 30 % of the footprint at the top (u_hi >= 0.9): the largest
back       upright, thin across one horizontal axis, every member at the same end of that axis
           (within its outer 20 %), reaching the upper quarter (u_hi >= 0.75, u_mid >= 0.5)
arms       two or more members at both ends of one horizontal axis, off the floor (u_lo >= 0.15),
           below the top (u_hi <= 0.9)
shelf      horizontal slabs over >= 30 % of the footprint, neither the top nor the bottom board
door       an upright panel (thin across a horizontal axis) at one end of that axis, >= 30 % of
           the height and >= 25 % of the width
side       upright panels at the ends of a horizontal axis, >= 40 % of the height
drawer     box-like members (thinnest >= 15 % of the widest) stacked or side by side (2 or more),
           at one end of a horizontal axis
base       on the floor (u_lo <= 0.05, u_hi <= 0.3) over >= 15 % of the footprint
rungs      horizontal bars (longest >= 3x the others) off the floor, in the lower half
frame      bars (longest >= 5x the thinnest)
handle     small (<= 20 % of the shape's area, no longer than 60 % of it) and not the largest
           group, at a horizontal end
body       the largest group by area
cushion    slabs over >= 10 % of the footprint at mid height (one or more)
========== ==================================================================================
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any, Callable

import numpy as np

from .names import matchable_words, same_word
from .prompt import parse_prompt
from .regions import RegionPlan, _label_of, split_regions

__all__ = ["PART_WORDS", "KINDRED", "GroupGeometry", "PartPlan", "describe_groups", "part_word", "resolve_words", "plan_parts",
           "new_part_texts"]


@dataclass(frozen=True)
class GroupGeometry:
    """What a part group is, in the shape's frame.

    Attributes:
        group: group index.
        members: number of member parts.
        up: index of the up axis (0, 1, 2); ``horizontal``: the other two.
        extent: (3,) one member's bounding-box extents relative to the shape's largest extent.
        shape_extent: (3,) the shape's extents relative to its largest (1 on the longest axis).
        lo, hi: (3,) the members' union box in the shape's box taken to [0, 1] per axis.
        centers: (members, 3) member box centres in the same [0, 1] frame.
        area_share: the group's share of the shape's surface area.
    """

    group: int
    members: int
    up: int
    horizontal: tuple[int, int]
    extent: np.ndarray
    shape_extent: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    centers: np.ndarray
    area_share: float

    @property
    def u_lo(self) -> float:
        return float(self.lo[self.up])

    @property
    def u_hi(self) -> float:
        return float(self.hi[self.up])

    @property
    def u_mid(self) -> float:
        return float(self.centers[:, self.up].mean())

    def footprint(self) -> float:
        """One member's horizontal box area over the shape's."""
        a, b = self.horizontal
        whole = self.shape_extent[a] * self.shape_extent[b]
        return float(self.extent[a] * self.extent[b] / whole) if whole > 0 else 0.0

    def flat(self) -> bool:
        """A horizontal slab: thickness at most half its smaller horizontal extent."""
        a, b = self.horizontal
        return bool(self.extent[self.up] <= 0.5 * min(self.extent[a], self.extent[b]))

    def upright_bar(self) -> bool:
        a, b = self.horizontal
        return bool(self.extent[self.up] >= 2.0 * max(self.extent[a], self.extent[b]))

    def height_share(self) -> float:
        """One member's height over the shape's."""
        return float(self.extent[self.up] / self.shape_extent[self.up]) if self.shape_extent[self.up] > 0 else 0.0

    def width_share(self, axis: int) -> float:
        return float(self.extent[axis] / self.shape_extent[axis]) if self.shape_extent[axis] > 0 else 0.0

    def at_one_end(self, axis: int, band: float = 0.2) -> bool:
        """Every member's centre within the outer ``band`` of ``axis``, all at the same end."""
        c = self.centers[:, axis]
        return bool(np.all(c <= band) or np.all(c >= 1.0 - band))

    def at_both_ends(self, axis: int, band: float = 0.25) -> bool:
        c = self.centers[:, axis]
        return bool(self.members >= 2 and c.min() <= band and c.max() >= 1.0 - band)

    def thin_across(self, axis: int, ratio: float = 0.5) -> bool:
        """Thin across ``axis`` compared with its other two extents (an upright panel or bar)."""
        others = [self.extent[i] for i in range(3) if i != axis]
        return bool(self.extent[axis] <= ratio * max(others))

    def slenderness(self) -> float:
        e = np.sort(self.extent)
        return float(e[2] / max(e[0], 1e-12))


def describe_groups(vertices: np.ndarray, faces: np.ndarray, grouping: Any, up: str | int = "z") -> list[GroupGeometry]:
    """One :class:`GroupGeometry` per non-degenerate group of ``grouping`` (a
    :class:`proctex.geometry.parts.Grouping`) on the mesh ``vertices (n, 3) float``, ``faces (m, 3)
    int``; ``up`` is "x", "y", "z" or an axis index."""
    u = "xyz".index(up) if isinstance(up, str) else int(up)
    if u not in (0, 1, 2):
        raise ValueError(f"up must be x, y or z, got {up!r}")
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or not len(v):
        raise ValueError(f"vertices must be (n, 3) with n > 0, got {v.shape}")
    parts = grouping.segmentation.parts
    used = np.unique(np.concatenate([p.vertices for p in parts if not p.degenerate] or [np.arange(len(v))]))
    lo, hi = v[used].min(0), v[used].max(0)
    span = hi - lo
    longest = float(span.max()) or 1.0
    safe = np.where(span > 0, span, 1.0)
    total = sum(p.area for p in parts if not p.degenerate) or 1.0
    horizontal = tuple(i for i in range(3) if i != u)
    out = []
    for g in grouping.groups:
        if g.degenerate:
            continue
        boxes = []
        for m in g.members:
            pv = v[parts[m].vertices]
            boxes.append((pv.min(0), pv.max(0)))
        mlo = np.array([b[0] for b in boxes])
        mhi = np.array([b[1] for b in boxes])
        rep = boxes[0]
        out.append(GroupGeometry(
            group=g.index, members=len(g.members), up=u, horizontal=horizontal,  # type: ignore[arg-type]
            extent=(rep[1] - rep[0]) / longest, shape_extent=span / longest,
            lo=(mlo.min(0) - lo) / safe, hi=(mhi.max(0) - lo) / safe,
            centers=((mlo + mhi) / 2 - lo) / safe,
            area_share=float(sum(parts[m].area for m in g.members) / total),
        ))
    return out


# ------------------------------------------------------------------------------------------ tests
def _floor(g: GroupGeometry, all_: list[GroupGeometry]) -> float:
    """Where legs stand: the floor (0), or the top of a flat base on it (a plinth) other than ``g``."""
    return max([h.u_hi for h in all_ if h.group != g.group and h.flat() and _base(h, all_) > 0] + [0.0])


def _legs(g: GroupGeometry, all_: list[GroupGeometry]) -> float:
    post = g.upright_bar() and max(g.width_share(a) for a in g.horizontal) <= 0.3  # not a cabinet's side board
    if g.u_lo > _floor(g, all_) + 0.1 or not (post or g.u_hi <= 0.6):
        return 0.0
    if g.flat() and g.footprint() >= 0.6:
        return 0.0
    return 1.0 if post else 0.7


def _seat_like(g: GroupGeometry, all_: list[GroupGeometry]) -> bool:
    """A slab off the floor with no other large slab above it (that would make it a shelf); the
    highest part when nothing rises above it (a stool, a chair without back or arms)."""
    if not g.flat() or g.footprint() < 0.25 or g.u_mid < 0.2:
        return False
    return not any(h.group != g.group and h.flat() and h.footprint() >= 0.3 and h.u_lo > g.u_hi for h in all_)


def _seat(g: GroupGeometry, all_: list[GroupGeometry]) -> float:
    if not _seat_like(g, all_):
        return 0.0
    # A seat at the very top (a stool's) is also a top: named both, "top" takes it.
    return (0.6 if g.u_hi >= 0.9 else 1.0) * _largest(g, all_, lambda h: _seat_like(h, all_), GroupGeometry.footprint)


def _top(g: GroupGeometry, all_: list[GroupGeometry]) -> float:
    if not g.flat() or g.footprint() < 0.3 or g.u_hi < 0.9:
        return 0.0
    return _largest(g, all_, lambda h: h.flat() and h.footprint() >= 0.3 and h.u_hi >= 0.9, GroupGeometry.footprint)


def _back(g: GroupGeometry, all_: list[GroupGeometry]) -> float:
    if g.u_hi < 0.75 or g.u_mid < 0.5:
        return 0.0
    ok = [a for a in g.horizontal if g.at_one_end(a) and g.thin_across(a)]
    return 0.9 if ok else 0.0


def _arms(g: GroupGeometry, all_: list[GroupGeometry]) -> float:
    if g.members < 2 or g.u_lo < 0.15 or g.u_hi > 0.9:
        return 0.0
    return 0.8 if any(g.at_both_ends(a) for a in g.horizontal) else 0.0


def _shelf(g: GroupGeometry, all_: list[GroupGeometry]) -> float:
    if not g.flat() or g.footprint() < 0.3:
        return 0.0
    return 0.8 if g.u_hi < 0.97 and g.u_lo > 0.03 else 0.0


def _door(g: GroupGeometry, all_: list[GroupGeometry]) -> float:
    for a, b in (g.horizontal, g.horizontal[::-1]):
        if g.thin_across(a, 0.2) and g.at_one_end(a, 0.15) and g.height_share() >= 0.3 and g.width_share(b) >= 0.25:
            return 0.8
    return 0.0


def _side(g: GroupGeometry, all_: list[GroupGeometry]) -> float:
    for a in g.horizontal:
        if g.thin_across(a, 0.25) and g.height_share() >= 0.4 and (g.at_both_ends(a, 0.15) or g.at_one_end(a, 0.15)):
            return 0.6
    return 0.0


def _drawer(g: GroupGeometry, all_: list[GroupGeometry]) -> float:
    e = np.sort(g.extent)
    if g.members < 2 or e[0] < 0.15 * e[2]:
        return 0.0
    return 0.8 if any(g.at_one_end(a, 0.35) for a in g.horizontal) else 0.0


def _base(g: GroupGeometry, all_: list[GroupGeometry]) -> float:
    return 0.8 if g.u_lo <= 0.05 and g.u_hi <= 0.3 and g.footprint() >= 0.15 else 0.0


def _rungs(g: GroupGeometry, all_: list[GroupGeometry]) -> float:
    e = g.extent
    long_axis = int(np.argmax(e))
    if long_axis == g.up or e[long_axis] < 3.0 * np.max(np.delete(e, long_axis)):
        return 0.0
    return 0.9 if g.u_lo >= 0.03 and g.u_mid <= 0.5 else 0.0


def _frame(g: GroupGeometry, all_: list[GroupGeometry]) -> float:
    return 0.5 if g.slenderness() >= 5.0 else 0.0


def _handle(g: GroupGeometry, all_: list[GroupGeometry]) -> float:
    if len(all_) < 2 or g.area_share > 0.2 or g.area_share >= max(h.area_share for h in all_) or g.extent.max() > 0.6:
        return 0.0
    return 0.7 if any(g.at_one_end(a, 0.3) or g.at_both_ends(a, 0.3) for a in g.horizontal) else 0.0


def _body(g: GroupGeometry, all_: list[GroupGeometry]) -> float:
    return 0.5 if g.area_share >= max(h.area_share for h in all_) else 0.0


def _cushion(g: GroupGeometry, all_: list[GroupGeometry]) -> float:
    return 0.7 if g.flat() and g.footprint() >= 0.1 and 0.2 <= g.u_mid <= 0.8 else 0.0


def _largest(g: GroupGeometry, all_: list[GroupGeometry], passes: Callable[[GroupGeometry], bool],
             key: Callable[[GroupGeometry], float]) -> float:
    """1 for the largest group passing ``passes`` by ``key`` (the one seat of a chair), else 0."""
    best = max((h for h in all_ if passes(h)), key=key, default=None)
    return 1.0 if best is not None and best.group == g.group else 0.0


#: canonical word -> (the forms a prompt may use, the test, why in one phrase for the notes)
PART_WORDS: dict[str, tuple[tuple[str, ...], Callable[[GroupGeometry, list[GroupGeometry]], float], str]] = {
    "legs": (("leg", "legs", "feet", "foot"), _legs, "stands on the floor"),
    "seat": (("seat", "seats", "saddle"), _seat, "the largest horizontal slab off the floor with none above it"),
    "top": (("top", "tabletop", "table-top", "worktop", "countertop", "tops"), _top, "the largest horizontal slab at the top"),
    "back": (("back", "backrest", "backs", "backrests"), _back, "upright at one end, reaching the upper part"),
    "arms": (("arm", "arms", "armrest", "armrests"), _arms, "a pair at both sides, off the floor"),
    "shelf": (("shelf", "shelves", "board", "boards"), _shelf, "horizontal slabs between top and bottom"),
    "door": (("door", "doors"), _door, "an upright panel at the front or back"),
    "side": (("side", "sides", "panel", "panels"), _side, "upright panels at the ends"),
    "drawer": (("drawer", "drawers"), _drawer, "box-like members at one end"),
    "base": (("base", "pedestal", "plinth", "stand"), _base, "on the floor, covering part of the footprint"),
    "rungs": (("rung", "rungs", "stretcher", "stretchers", "crossbar", "crossbars", "support", "supports"), _rungs,
              "horizontal bars off the floor, in the lower half"),
    "frame": (("frame", "frames", "bars", "bar"), _frame, "slender bars"),
    "handle": (("handle", "handles", "knob", "knobs", "pull", "pulls"), _handle, "a small part at the side"),
    "body": (("body",), _body, "the largest group"),
    "cushion": (("cushion", "cushions", "pillow", "pillows"), _cushion, "slabs at mid height"),
}

_FORMS = {form: word for word, (forms, _, _) in PART_WORDS.items() for form in forms}


#: Words of one kind: what holds a shape up. A group the prompt does not name that passes the test of
#: one of them takes the clause of another the prompt placed ("dark walnut legs" paints a chair's disc
#: base and its stretchers), before the rest of the prompt or the most alike shape.
KINDRED: tuple[tuple[str, ...], ...] = (("legs", "base", "rungs"),)


def part_word(form: str) -> str | None:
    """The canonical word of ``form`` ("legs" for "leg", "feet"; None when not a part word)."""
    return _FORMS.get(str(form).lower())


@lru_cache(maxsize=4096)
def _material_word(word: str) -> bool:
    """Whether the prompt parser reads ``word`` as a colour, material or pattern ("oak", "red")."""
    return bool(parse_prompt(word).understood)


def label_hits(token: str, labels: list[str]) -> list[str]:
    """The labels (several words each, as a node tree names parts: "Left Arm", "Back Rest") that
    ``token`` names: one of a label's words up to a plural (:func:`.names.same_word`),
    or, for a part word, one of its forms ("feet" names "Legs"). Qualifiers ("left", "front"),
    words that name no part and colour or material words ("Oak" of "Oak Panel": "oak" in a prompt is
    a material) are never matched."""
    token = token.lower()
    if _material_word(token):
        return []
    word = part_word(token)
    forms = (token,) + (PART_WORDS[word][0] if word else ())
    out = []
    for lab in dict.fromkeys(labels):
        if any(same_word(f, w) for w in matchable_words(lab) if not _material_word(w) for f in forms):
            out.append(lab)
    return out


def resolve_words(words: list[str], geoms: list[GroupGeometry]) -> dict[str, tuple[list[int], str]]:
    """Groups each canonical word of ``words`` takes: ``{word: (group ids, why)}``; words no group
    passes are left out. A group passing several of the words goes to the highest score (the first
    word of :data:`PART_WORDS` on a tie), so "seat and legs" never share a group."""
    scores: dict[str, dict[int, float]] = {}
    for word in dict.fromkeys(words):
        if word not in PART_WORDS:
            raise ValueError(f"unknown part word {word!r}; known: {', '.join(PART_WORDS)}")
        test = PART_WORDS[word][1]
        got = {g.group: s for g in geoms if (s := float(test(g, geoms))) > 0}
        if got:
            scores[word] = got
    order = list(PART_WORDS)
    owner: dict[int, str] = {}
    for word, got in scores.items():
        for gid, s in got.items():
            cur = owner.get(gid)
            if cur is None or (s, -order.index(word)) > (scores[cur][gid], -order.index(cur)):
                owner[gid] = word
    out: dict[str, tuple[list[int], str]] = {}
    for gid, word in sorted(owner.items()):
        out.setdefault(word, ([], PART_WORDS[word][2]))[0].append(gid)
    return out


# ------------------------------------------------------------------------------------------- plan
@dataclass
class PartPlan:
    """A prompt resolved against one shape's part groups.

    Attributes:
        prompt: the prompt as given.
        regions: the :class:`RegionPlan` of the prompt with the resolved part words as part names.
        texts: group id -> the text that group is painted with, in the group's own frame, for groups
            that do not simply take the whole prompt (a clause naming the group, a borrowed clause,
            or the rest joined by an unplaced clause's material).
        words: canonical word -> group ids it took.
        notes: human-readable lines: which groups each word took and why, borrowed materials,
            clauses that could not be placed and where their material went.
    """

    prompt: str
    regions: RegionPlan
    texts: dict[int, str] = field(default_factory=dict)
    words: dict[str, list[int]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def text_for(self, group: int) -> str:
        """What group ``group`` is painted with: its clause, else the whole prompt."""
        return self.texts.get(group, self.prompt)


def _understood(text: str) -> bool:
    return bool(text.strip()) and bool(parse_prompt(text).understood)


def _shape_key(g: GroupGeometry) -> np.ndarray:
    """Slab or bar: the log ratios of one member's sorted extents to its longest, the middle one
    (flat panels near 1, bars small) weighing four times the thinnest."""
    e = np.sort(np.maximum(g.extent, 1e-6))
    return np.log(e[:2] / e[2]) * np.array([0.25, 1.0])


def plan_parts(prompt: str, vertices: np.ndarray, faces: np.ndarray, grouping: Any, up: str | int = "z") -> PartPlan:
    """Resolve ``prompt`` against the part groups of a mesh (module docstring).

    Args:
        prompt: any string (``ValueError`` otherwise).
        vertices, faces: the shape (``(n, 3)`` float, ``(m, 3)`` int).
        grouping: its :class:`proctex.geometry.parts.Grouping` (labels, where present, come first).
        up: the shape's up axis.
    Returns:
        :class:`PartPlan`.
    """
    if not isinstance(prompt, str):
        raise ValueError(f"prompt must be a string, got {type(prompt).__name__}")
    labels = [g.label for g in grouping.groups if g.label]
    label_map = {lab.lower(): lab for lab in labels}
    tokens = re.findall(r"[\w'-]+", prompt.lower())
    # A word naming a word of a group's label ("arms" for "Left Arm", "feet" for "Legs": a form of the
    # same part word) routes by the label: labels beat geometry.
    by_word = {t: hit for t in dict.fromkeys(tokens) if _label_of(t, label_map) is None and (hit := label_hits(t, labels))}
    wanted = list(dict.fromkeys(part_word(t) for t in tokens if part_word(t) and _label_of(t, label_map) is None and t not in by_word))
    geoms = describe_groups(vertices, faces, grouping, up) if wanted else []
    # A word only becomes a part where the shape has more than one group: on a one-part vase "top"
    # and "base" stay regions of that part.
    resolved = resolve_words(wanted, geoms) if len(geoms) > 1 else {}
    named = {lab for t in tokens for lab in ([_label_of(t, label_map)] if _label_of(t, label_map) else by_word.get(t, []))}
    if named:  # a group the prompt names by its label is not also taken by a word's geometric test
        taken = {g.index for g in grouping.groups if g.label in named}
        resolved = {w: (kept, why) for w, (gids, why) in resolved.items() if (kept := [g for g in gids if g not in taken])}
    forms = [f for w in resolved for f in PART_WORDS[w][0]]
    regions = split_regions(prompt, labels + list(by_word) + forms)
    by_form = {f: w for w in resolved for f in PART_WORDS[w][0]}
    plan = PartPlan(prompt, regions, words={w: gids for w, (gids, _) in resolved.items()})
    label_groups: dict[str, list[int]] = {}
    for g in grouping.groups:
        if g.label:
            label_groups.setdefault(g.label, []).append(g.index)
    clause_of: dict[int, str] = {}
    for name, text in regions.parts:
        if name in label_groups:
            gids = label_groups[name]
        elif name in by_word:
            gids = sorted({gid for lab in by_word[name] for gid in label_groups.get(lab, [])})
            plan.notes.append(f"{name!r} names the group(s) labelled {', '.join(repr(lab) for lab in by_word[name])}: "
                              f"{', '.join(map(str, gids))}")
        else:
            word = by_form.get(name) or part_word(name)
            gids = resolved.get(word, ([], ""))[0] if word else []
        for gid in gids:
            clause_of[gid] = text
    for word, (gids, why) in resolved.items():
        if any(gid in clause_of for gid in gids):
            plan.notes.append(f"{word!r} took group(s) {', '.join(map(str, gids))}: {why}")
    for word in wanted:
        if word not in resolved:
            plan.notes.append(f"{word!r}: no part of this shape passes its test ({PART_WORDS[word][2]})")
    rest = regions.base
    unplaced = [t for t in regions.unplaced if _understood(t)]
    if unplaced and not _understood(rest):
        plan.notes.append(f"clause(s) {', '.join(repr(t) for t in unplaced)} named no part of this shape; "
                          "their material paints the rest")
        rest = " ".join([rest, *unplaced]).strip()
    plan.texts.update(clause_of)
    others = [g for g in grouping.groups if not g.degenerate and g.index not in clause_of]
    kin = _kindred_texts(others, plan.words, clause_of, geoms or describe_groups(vertices, faces, grouping, up)) if clause_of and others else {}
    for gid, (text, word, kind) in kin.items():
        plan.texts[gid] = text
        plan.notes.append(f"group {gid} passes the test of {kind!r} and takes the clause of {word!r}, of the same kind: {text!r}")
    others = [g for g in others if g.index not in kin]
    if _understood(rest):
        # The rest of the shape: the rest of the prompt (in the whole shape's frame, with its regions,
        # unless an unplaced clause had to join it) ...
        if rest != regions.base:
            for g in others:
                plan.texts[g.index] = rest
    elif clause_of and others and not regions.regions:
        # ... else (when no region of the whole shape is named either) the clause of the group most
        # alike in shape.
        key = {g.group: _shape_key(g) for g in (geoms or describe_groups(vertices, faces, grouping, up))}
        for g in others:
            if g.index not in key:
                continue
            near = min(clause_of, key=lambda c: (float(np.abs(key[g.index] - key[c]).sum()) if c in key else np.inf, c))
            plan.texts[g.index] = clause_of[near]
            plan.notes.append(f"group {g.index} is named by no clause and the rest of the prompt names no material: "
                              f"it takes {clause_of[near]!r} from group {near}, the most alike in shape")
    return plan


def _kindred_texts(others: list[Any], words: dict[str, list[int]], clause_of: dict[int, str],
                   geoms: list[GroupGeometry]) -> dict[int, tuple[str, str, str]]:
    """``{group: (text, placed word, kindred word it passes)}`` for the groups of ``others`` that
    pass the test of a :data:`KINDRED` word whose kin the plan placed (``words``, ``clause_of``)."""
    by_id = {g.group: g for g in geoms}
    out: dict[int, tuple[str, str, str]] = {}
    for kin in KINDRED:
        placed = [w for w in kin if any(gid in clause_of for gid in words.get(w, []))]
        if not placed:
            continue
        word = placed[0]
        text = clause_of[next(gid for gid in words[word] if gid in clause_of)]
        for g in others:
            geo = by_id.get(g.index)
            if geo is None or g.index in out:
                continue
            for k in kin:
                if k not in placed and PART_WORDS[k][1](geo, geoms) > 0:
                    out[g.index] = (text, word, k)
                    break
    return out


def new_part_texts(prompt: str, shape: Any, segmentation: Any, parts: list[int], up: str | int = "z") -> dict[int, str]:
    """What parts of a new shape that match no template group are painted with: the prompt resolved
    on the new shape itself (its parts grouped by kind, :func:`proctex.geometry.parts.kind_groups`),
    so "brass arms" paints arms the template lacked; ``{part: text}`` for the parts a clause (or a
    borrowed clause, or the rest joined by an unplaced clause) names, the others take the whole
    prompt's rest."""
    from proctex.geometry.parts import kind_groups

    if not parts:
        return {}
    grouping = kind_groups(shape, segmentation)
    plan = plan_parts(prompt, shape.vertices, shape.faces, grouping, up)
    out = {}
    for p in parts:
        g = int(grouping.part_group[p])
        if g in plan.texts:
            out[int(p)] = plan.texts[g]
    return out
