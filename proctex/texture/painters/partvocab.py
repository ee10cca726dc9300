"""The words users write for parts, by kinds of object, each with a small scoring function of a
part group's evidence (issue 51).

One table (:data:`WORDS`) serves every painter. A *word* is canonical ("legs"); its *forms* are what
a prompt may say ("leg", "feet", "table legs"); compounds of two words ("table top", "drawer
fronts", "seat cushions") are joined before a prompt is split (:func:`join_compounds`). A word may
mean different parts in different kinds of object ("handle": a mug's loop, a cabinet's knob, a
hammer's shaft), so each kind that uses it has its own scorer. :data:`NOUNS` maps an object noun
("a lamp", "a car") to its kind; without one, the kind whose words the prompt uses most is tried
first (:func:`kind_of`), else every kind's scorer and the best of them.

A scorer maps a group's :class:`Evidence` (and every group's, for relations) to [0, 1]: products of
soft conditions on measured evidence, never a rule that names one file:

- shape of one member from its principal axes: a *bar* (longest >= 3x the middle), a *plate* (thinnest
  <= 0.3x the middle), lying flat or upright (the thinnest axis along up or across it), a *blob*
  (thinnest >= 0.4x the longest), a *disc* (a round plate);
- height band in the shape (u: 0 floor, 1 top), on the floor or not;
- support: what it rests on and what rests on it (boxes touching along up, overlapping across);
- repetition: members, at both ends of a horizontal axis (a mirrored pair), at the corners;
- place against the main mass (the largest group by area): above it, under it, beside it,
  protruding out of its box;
- size: share of the area and its rank.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from .names import same_word
from .partevidence import (  # noqa: F401  (the evidence, read from here by the painters and tests)
    Evidence,
    ramp,
    fall,
    evidence,
    bar,
    upright_bar,
    lying_bar,
    plate,
    flat_plate,
    upright_plate,
    blob,
    wheel_disc,
    on_floor,
    off_floor,
    at_top,
    low,
    band,
    small,
    main_mass,
    not_main,
    at_an_end,
    pair_at_ends,
    holds_something,
    rests,
    by_id,
    main_of,
    outside_main,
    above_main,
    under,
    largest_of,
    lowest,
    longest,
)

__all__ = ["Evidence", "WORDS", "NOUNS", "KINDS", "evidence", "word_of", "kind_of", "join_compounds", "join_compounds_text", "score"]


# ------------------------------------------------------------------------------------- scorers
Scorer = Callable[[Evidence, list[Evidence]], float]


def grounded(e: Evidence, all_: list[Evidence]) -> float:
    """On the floor, or on a low wide part that is (a plinth, a base board)."""
    ids = by_id(all_)
    on_base = any(x in ids and ids[x].u_lo <= 0.05 and ids[x].footprint() >= 0.3 and ids[x].u_hi <= 0.3 for x in e.rests_on)
    return max(on_floor(e), 1.0 if on_base else 0.0)


def legs(e, all_):
    spans = ramp(float(e.hi[e.up] - e.lo[e.up]), 0.3, 0.5) * (1 - flat_plate(e)) * (1.0 if e.holds else 0.0)  # a frame of legs in one piece
    support = max(upright_bar(e), 0.8 * upright_plate(e) * pair_at_ends(e), 0.6 * fall(max(e.extent[a] for a in e.horizontal), 0.15, 0.3), 0.7 * spans)
    slab = flat_plate(e) * ramp(e.footprint(), 0.3, 0.6)
    return grounded(e, all_) * support * holds_something(e) * (1.0 if e.members >= 2 else 0.6) * (1 - slab) * not_main(e)


def seat(e, all_):
    # a seat at the very top (a stool's) is also a top: named both, "top" takes it
    return flat_plate(e) * ramp(e.footprint(), 0.15, 0.3) * off_floor(e) * max(band(e, 0.2, 0.7), 0.6 * at_top(e)) * largest_of(e, all_, lambda x: flat_plate(x) * off_floor(x), Evidence.footprint)


def cushions(e, all_):
    return (0.5 + 0.5 * max(flat_plate(e), blob(e))) * off_floor(e) * band(e, 0.25, 0.75) * rests(e) * not_main(e) * fall(e.height_share(), 0.4, 0.6)


def back(e, all_):
    """Upright at one end reaching the upper part: a panel, or bars (posts, slats, spindles)."""
    tall = ramp(float(e.hi[e.up] - e.lo[e.up]), 0.15, 0.3)
    return max(upright_plate(e), 0.8 * bar(e)) * at_an_end(e) * ramp(e.u_hi, 0.7, 0.85) * tall


def mirrored(e: Evidence, all_: list[Evidence]) -> float:
    """A pair: members at both ends of a horizontal axis, or another group of about its size at
    the other end (left and right parts built a little differently)."""
    best = pair_at_ends(e)
    for x in all_:
        if x.group == e.group or x.members != e.members:
            continue
        alike = fall(float(np.abs(np.log(np.maximum(x.axes, 1e-9) / np.maximum(e.axes, 1e-9))).max()), 0.2, 0.5)
        for a in e.horizontal:
            ca, cb = e.centers[:, a].mean(), x.centers[:, a].mean()
            opposite = fall(abs(ca + cb - 1.0), 0.05, 0.15) * ramp(abs(ca - 0.5), 0.2, 0.35)
            best = max(best, alike * opposite)
    return best


def outermost(e: Evidence) -> float:
    """Its members reach both outer sides of a horizontal axis (or one member one side)."""
    best = 0.0
    for a in e.horizontal:
        out = max(e.lo[a], 1 - e.hi[a]) if e.members >= 2 else min(e.lo[a], 1 - e.hi[a])
        best = max(best, fall(out, 0.06, 0.15))
    return best


def arms(e, all_):
    return mirrored(e, all_) * outermost(e) * off_floor(e) * band(e, 0.3, 0.85) * (1 - upright_bar(e)) * fall(e.members, 2.5, 3.5)


def top(e, all_):
    return flat_plate(e) * ramp(e.footprint(), 0.25, 0.5) * at_top(e) * largest_of(e, all_, flat_plate, Evidence.footprint)


def apron(e, all_):
    """A shallow band right under the top (boards, rails or one frame), off the floor."""
    tops = [x for x in all_ if x.group != e.group and top(x, all_) > 0.5]
    below_top = max((fall(abs(e.u_hi - t.u_lo), 0.03, 0.1) for t in tops), default=0.0)
    return below_top * off_floor(e) * fall(float(e.hi[e.up] - e.lo[e.up]), 0.2, 0.35) * (1 - upright_bar(e))


def drawers(e, all_):
    return (
        at_an_end(e)
        * off_floor(e)
        * fall(e.u_hi, 0.97, 1.0)
        * not_main(e)
        * fall(e.height_share(), 0.4, 0.6)
        * (1 - upright_bar(e))
        * (1 - flat_plate(e) * ramp(e.footprint(), 0.4, 0.6))
        * small(e, 0.2)
    )


def doors(e, all_):
    return upright_plate(e) * at_an_end(e) * ramp(e.height_share(), 0.25, 0.4) * not_main(e) * fall(e.union_footprint(), 0.5, 0.8)


def handles(e, all_):
    return small(e, 0.03) * not_main(e) * max(outside_main(e, all_), at_an_end(e)) * off_floor(e) * fall(e.axes[0], 0.3, 0.5)


def body(e, all_):
    return main_mass(e)


def base(e, all_):
    """Low and wide under the rest: on the floor, on legs, or just above the floor; no wide part under it."""
    wide_below = any(x.group != e.group and x.footprint() >= 0.5 * e.footprint() and x.u_hi <= e.u_lo + 0.02 for x in all_)
    return low(e, 0.4) * ramp(e.footprint(), 0.08, 0.2) * holds_something(e) * (1 - 0.5 * bar(e)) * (0.4 if wide_below else 1.0) * max(on_floor(e), 1.0 if e.rests_on else 0.0, fall(e.u_lo, 0.15, 0.3))


def lamp_base(e, all_):
    """The lowest part on the floor holding the rest up (a disc, a weight, a bulbous foot)."""
    return on_floor(e) * low(e, 0.6) * holds_something(e) * (1 - bar(e)) * lowest(e, all_) * ramp(e.footprint(), 0.05, 0.15)


def shelf(e, all_):
    return flat_plate(e) * ramp(e.footprint(), 0.2, 0.4) * off_floor(e) * fall(e.u_hi, 0.9, 0.97)


def sides(e, all_):
    return upright_plate(e) * pair_at_ends(e) * ramp(e.height_share(), 0.3, 0.5)


def rungs(e, all_):
    return lying_bar(e) * off_floor(e) * fall(e.u_mid, 0.45, 0.6) * fall(e.u_lo, 0.5, 0.6)


def frame(e, all_):
    bed_frame = (1.0 if e.holds else 0.0) * off_floor(e) * low(e, 0.45) * ramp(e.footprint(), 0.3, 0.6)
    return max(0.6 * bar(e), bed_frame) * (1.0 if e.rank else 0.5)


def mattress(e, all_):
    return max(flat_plate(e), 0.7 * blob(e)) * ramp(e.footprint(), 0.3, 0.6) * off_floor(e) * band(e, 0.15, 0.6) * rests(e) * fall(e.height_share(), 0.4, 0.6)


def headboard(e, all_):
    return upright_plate(e) * at_an_end(e) * ramp(e.height_share(), 0.3, 0.5) * (0.5 + 0.5 * ramp(e.u_hi, 0.75, 0.98))


def footboard(e, all_):
    return upright_plate(e) * at_an_end(e) * ramp(e.height_share(), 0.15, 0.3) * (0.5 + 0.5 * fall(e.u_hi, 0.7, 0.97))


def pillows(e, all_):
    return rests(e) * off_floor(e) * small(e, 0.12) * not_main(e) * ramp(e.u_hi, 0.4, 0.6) * (1 - upright_plate(e)) * (1 - bar(e))


def slats(e, all_):
    return lying_bar(e) * (1.0 if e.members >= 3 else 0.3) * off_floor(e)


def shade(e, all_):
    return ramp(e.u_hi, 0.75, 0.95) * off_floor(e) * (1 - bar(e)) * band(e, 0.45, 1.0) * ramp(e.footprint(), 0.05, 0.2)


def pole(e, all_):
    return upright_bar(e) * not_main(e) * fall(e.footprint(), 0.05, 0.15) * (1.0 if e.holds or e.rests_on else 0.6)


def lamp_arm(e, all_):
    return bar(e) * fall(e.u_hi, 0.97, 1.0) * not_main(e) * (1 - 0.5 * upright_bar(e)) * (1 - 0.5 * on_floor(e) * lowest(e, all_)) * (1.0 if e.touches else 0.5)


def bulb(e, all_):
    return blob(e) * small(e, 0.05) * off_floor(e) * ramp(e.u_mid, 0.5, 0.7)


def vessel_body(e, all_):
    return main_mass(e) * (0.5 + 0.5 * blob(e))


def vessel_handle(e, all_):
    """A part sticking out of the body at one side that does not rise outward (a loop, a grip)."""
    return not_main(e) * off_floor(e) * outside_main(e, all_) * small(e, 0.15) * fall(e.u_hi, 0.95, 1.0) * (1 - 0.5 * at_top(e)) * fall(e.rise, 0.1, 0.4)


def spout(e, all_):
    """A bar sticking out of the body at one side whose outer end is higher."""
    return not_main(e) * bar(e) * outside_main(e, all_) * fall(e.long_up, 0.9, 0.98) * off_floor(e) * ramp(e.rise, 0.1, 0.4)


def on_top_of_main(e: Evidence, all_: list[Evidence]) -> float:
    """Its middle in the top fifth of the main mass's height or above, within its box across."""
    m = main_of(all_)
    if m.group == e.group:
        return 0.0
    h = max(m.hi[e.up] - m.lo[e.up], 1e-9)
    return ramp((e.u_mid - m.lo[e.up]) / h, 0.75, 0.9) * fall(outside_main(e, all_), 0.3, 0.8)


def lid(e, all_):
    return not_main(e) * ramp(e.u_hi, 0.9, 0.98) * on_top_of_main(e, all_) * small(e, 0.2) * (1 - bar(e))


def cup(e, all_):
    return at_top(e) * off_floor(e) * (1 - bar(e)) * ramp(e.footprint(), 0.2, 0.5)


def stem(e, all_):
    return upright_bar(e) * not_main(e) * (1 - at_top(e) * 0.7) * holds_something(e)


def foot(e, all_):
    return on_floor(e) * low(e, 0.25) * holds_something(e) * (1 - bar(e)) * ramp(e.footprint(), 0.2, 0.5)


def wheels(e, all_):
    return wheel_disc(e) * on_floor(e) * (1.0 if e.members >= 2 else 0.5) * not_main(e)


def cabin(e, all_):
    m = main_of(all_)
    at_end = max(ramp(abs(e.centers[:, a].mean() - 0.5), 0.2, 0.35) for a in e.horizontal)
    beside = at_end * (1.0 if m.group in e.touches else 0.5) * off_floor(e)
    return not_main(e) * (1 - wheel_disc(e)) * max(above_main(e, all_), 0.8 * beside) * ramp(e.area_share, 0.05, 0.12) * fall(e.members, 1.5, 2.5)


def bumpers(e, all_):
    return pair_at_ends(e) * low(e, 0.45) * not_main(e) * (1 - wheel_disc(e)) * off_floor(e)


def car_roof(e, all_):
    return at_top(e) * not_main(e) * flat_plate(e)


def walls(e, all_):
    return main_mass(e) * on_floor(e)


def roof(e, all_):
    """The upper cover: over most of the footprint, no part as large above it, resting on the rest."""
    covered = any(x.group != e.group and x.u_lo >= e.u_mid and x.area_share >= 0.5 * e.area_share for x in all_)
    return ramp(e.u_hi, 0.6, 0.8) * not_main(e) * off_floor(e) * ramp(e.footprint(), 0.4, 0.7) * rests(e) * (0.3 if covered else 1.0)


def house_door(e, all_):
    return upright_plate(e) * on_floor(e) * at_an_end(e) * not_main(e) * fall(e.height_share(), 0.6, 0.8) * (1.0 if e.members == 1 else 0.7)


def windows(e, all_):
    return upright_plate(e) * off_floor(e) * at_an_end(e) * not_main(e) * fall(e.height_share(), 0.4, 0.6) * small(e, 0.08)


def chimney(e, all_):
    return at_top(e) * not_main(e) * fall(e.footprint(), 0.05, 0.15) * (1 - plate(e)) * fall(e.members, 1.5, 2.5)


def trunk(e, all_):
    return upright_bar(e) * on_floor(e) * (holds_something(e) if e.rank else 0.7)


def canopy(e, all_):
    return off_floor(e) * ramp(e.u_hi, 0.7, 0.9) * (1 - upright_bar(e)) * (1 - bar(e) * 0.5) * ramp(e.area_share, 0.05, 0.15)


def branches(e, all_):
    return bar(e) * off_floor(e) * fall(e.long_up, 0.9, 0.98) * band(e, 0.3, 0.9)


def pot(e, all_):
    return on_floor(e) * low(e, 0.5) * holds_something(e) * (1 - bar(e)) * ramp(e.area_share, 0.1, 0.25)


def plant_stem(e, all_):
    return upright_bar(e) * off_floor(e) * not_main(e)


def carried_by_bar(e: Evidence, all_: list[Evidence]) -> float:
    """It sits on an upright bar narrower than it (a cap on its stem, a shade on its pole)."""
    ids = by_id(all_)
    return max((upright_bar(ids[x]) for x in e.touches if x in ids and ids[x].u_mid < e.u_mid and ids[x].footprint() < e.footprint()), default=0.0)


def carries(e: Evidence, all_: list[Evidence]) -> float:
    """Something wider stands on it or sits on its top."""
    ids = by_id(all_)
    return 1.0 if e.holds or any(x in ids and ids[x].u_mid > e.u_mid and ids[x].footprint() > e.footprint() for x in e.touches) else 0.4


def cap(e, all_):
    return (1 - bar(e)) * max(at_top(e) * ramp(e.footprint(), 0.3, 0.6) * rests(e), carried_by_bar(e, all_))


def mushroom_stem(e, all_):
    return max(upright_bar(e), 0.6 * blob(e) * fall(e.footprint(), 0.2, 0.4)) * on_floor(e) * carries(e, all_)


def shaft(e, all_):
    return bar(e) * longest(e, all_)


def head(e, all_):
    shafts = [x for x in all_ if x.group != e.group and bar(x) > 0.5]
    at_shaft_end = max((1.0 if (e.u_mid > x.u_hi - 0.1 or e.u_mid < x.u_lo + 0.1) else 0.4) for x in shafts) if shafts else 0.5
    return (1 - 0.7 * bar(e) * longest(e, all_)) * at_shaft_end * fall(e.members, 1.5, 2.5) * (1 - plate(e) * 0.3)


def blade(e, all_):
    return plate(e) * (1 - bar(e)) * fall(e.members, 1.5, 2.5)


# ------------------------------------------------------------------------------------------ table
#: kinds of object and the nouns that name them
KINDS: dict[str, tuple[str, ...]] = {
    "furniture": (
        "chair",
        "armchair",
        "stool",
        "bench",
        "table",
        "desk",
        "sofa",
        "couch",
        "settee",
        "cabinet",
        "cupboard",
        "wardrobe",
        "dresser",
        "sideboard",
        "bookcase",
        "bookshelf",
        "nightstand",
        "ottoman",
        "loveseat",
    ),
    "beds": ("bed", "bunk", "cot", "crib", "daybed"),
    "lighting": ("lamp", "lantern", "chandelier", "sconce", "floorlamp", "lamps"),
    "tableware": ("mug", "cup", "teapot", "kettle", "jug", "pitcher", "goblet", "vase", "bowl", "bottle", "tankard", "chalice", "teacup"),
    "vehicles": ("car", "truck", "lorry", "van", "bus", "jeep", "wagon", "cart", "tractor", "taxi", "pickup"),
    "buildings": ("house", "hut", "cottage", "shed", "barn", "building", "home", "villa", "bungalow", "cabin-house"),
    "plants": ("tree", "plant", "bush", "shrub", "mushroom", "toadstool", "fungus", "flower", "sapling", "palm", "oak-tree", "pine"),
    "tools": ("hammer", "axe", "ax", "shovel", "spade", "mallet", "hatchet", "rake", "pickaxe", "hoe", "sledgehammer"),
}
NOUNS: dict[str, str] = {n: k for k, nouns in KINDS.items() for n in nouns}


@dataclass(frozen=True)
class Word:
    """One part word: its forms, and per kind of object a scorer and why (for the notes)."""

    forms: tuple[str, ...]
    scorers: dict[str, tuple[Scorer, str]]


def _w(forms: str, **scorers: tuple[Scorer, str]) -> Word:
    return Word(tuple(forms.split()), dict(scorers))


_ANY = "any"  # a scorer for every kind without its own
WORDS: dict[str, Word] = {
    "legs": _w("leg legs feet table-legs chair-legs", any=(legs, "thin supports standing on the floor under something")),
    "seat": _w("seat seats saddle", any=(seat, "the largest slab lying flat off the floor, at sitting height")),
    "cushions": _w("cushion cushions seat-cushions seat-cushion", any=(cushions, "soft slabs resting on the frame at mid height")),
    "back": _w("back backs backrest backrests back-rest", any=(back, "an upright panel at one end, reaching the upper part")),
    "arms": _w("arm arms armrest armrests arm-rests", any=(arms, "a pair at both sides, off the floor"), lighting=(lamp_arm, "a bar off the floor, below the top")),
    "top": _w("top tops tabletop tabletops table-top worktop countertop desktop desk-top", any=(top, "the largest slab lying flat at the top"), vehicles=(car_roof, "a slab lying flat at the top")),
    "apron": _w("apron aprons rail rails skirt", any=(apron, "bars or boards right under the top"), beds=(frame, "the frame under the mattress")),
    "drawers": _w("drawer drawers drawer-front drawer-fronts", any=(drawers, "boxes or fronts at one end, off the floor")),
    "doors": _w("door doors", any=(doors, "an upright panel at one end, a good part of the height"), buildings=(house_door, "an upright panel on the floor, at a wall's face")),
    "handles": _w(
        "handle handles knob knobs pull pulls grip grips",
        any=(handles, "a small part sticking out at a side"),
        tableware=(vessel_handle, "a part sticking out of the body at one side"),
        tools=(shaft, "the longest bar"),
    ),
    "body": _w("body bodies carcass hull", any=(body, "the main mass"), tableware=(vessel_body, "the main mass")),
    "base": _w("base bases plinth pedestal stand", any=(base, "low and wide, under the rest"), lighting=(lamp_base, "the lowest part, on the floor, holding the rest up")),
    "shelf": _w("shelf shelves board boards", any=(shelf, "slabs lying flat between top and bottom")),
    "sides": _w("side sides panel panels side-panels", any=(sides, "upright panels at both ends")),
    "rungs": _w("rung rungs stretcher stretchers crossbar crossbars", any=(rungs, "bars lying across, off the floor, low")),
    "frame": _w("frame frames bed-frame side-rails bedframe", any=(frame, "bars, or what holds the mattress")),
    "mattress": _w("mattress mattresses", any=(mattress, "a thick slab lying flat on the frame")),
    "headboard": _w("headboard headboards head-board", any=(headboard, "the taller upright panel at one end")),
    "footboard": _w("footboard footboards foot-board", any=(footboard, "the lower upright panel at one end")),
    "pillows": _w("pillow pillows", any=(pillows, "small soft parts resting on top")),
    "slats": _w("slat slats", any=(slats, "bars lying in a row")),
    "shade": _w("shade shades lampshade lampshades lamp-shade", any=(shade, "the wide part at the top, off the floor")),
    "pole": _w("pole poles rod post", any=(pole, "an upright bar"), lighting=(pole, "an upright bar between base and shade")),
    "bulb": _w("bulb bulbs", any=(bulb, "a small round part near the top")),
    "spout": _w("spout spouts nozzle", any=(spout, "a bar rising out of the body at one side")),
    "lid": _w("lid lids", any=(lid, "a small part on top of the body")),
    "cup": _w("cup bowl", any=(cup, "the wide part at the top")),
    "stem": _w(
        "stem stems stalk",
        any=(stem, "an upright bar under something"),
        lighting=(pole, "an upright bar"),
        plants=(lambda e, a: max(plant_stem(e, a), mushroom_stem(e, a)), "an upright bar under the top"),
        tableware=(stem, "an upright bar between foot and cup"),
    ),
    "foot": _w("foot", any=(foot, "a wide low part on the floor"), furniture=(legs, "thin supports on the floor")),
    "wheels": _w("wheel wheels tyre tyres tire tires", any=(wheels, "round plates on edge, on the floor")),
    "cabin": _w("cabin cab cockpit", any=(cabin, "a box on top of the body or at its end")),
    "bumpers": _w("bumper bumpers", any=(bumpers, "a pair at both ends, low")),
    "roof": _w("roof roofs", any=(roof, "at the top, covering the footprint"), vehicles=(car_roof, "a slab at the top")),
    "walls": _w("wall walls facade", any=(walls, "the main mass on the floor")),
    "windows": _w("window windows", any=(windows, "small upright panels on a face, off the floor")),
    "chimney": _w("chimney chimneys", any=(chimney, "a narrow part rising at the top")),
    "trunk": _w("trunk trunks", any=(trunk, "an upright bar on the floor holding the rest")),
    "canopy": _w("canopy leaves foliage crown leaf", any=(canopy, "the mass at the top")),
    "branches": _w("branch branches", any=(branches, "bars off the floor, across or slanted")),
    "pot": _w("pot planter", any=(pot, "a container on the floor holding the plant")),
    "cap": _w("cap caps", any=(cap, "the wide part at the top")),
    "head": _w("head heads", any=(head, "the compact part at the end of the shaft")),
    "blade": _w("blade blades", any=(blade, "a flat plate at one end")),
    "shaft": _w("shaft shafts haft", any=(shaft, "the longest bar")),
}
# words of a kind: which kinds use a word (a word with only "any" belongs to the kinds listed here)
WORD_KINDS: dict[str, tuple[str, ...]] = {
    "furniture": ("legs", "seat", "cushions", "back", "arms", "top", "apron", "drawers", "doors", "handles", "body", "base", "shelf", "sides", "rungs", "frame"),
    "beds": ("legs", "frame", "mattress", "headboard", "footboard", "pillows", "slats", "apron", "base"),
    "lighting": ("shade", "pole", "arms", "base", "bulb", "stem"),
    "tableware": ("body", "handles", "spout", "lid", "cup", "stem", "foot", "base"),
    "vehicles": ("body", "cabin", "wheels", "bumpers", "roof", "doors", "windows", "top"),
    "buildings": ("walls", "roof", "doors", "windows", "chimney"),
    "plants": ("trunk", "canopy", "branches", "pot", "cap", "stem"),
    "tools": ("handles", "head", "blade", "shaft"),
}

_FORMS: dict[str, str] = {f: w for w, word in WORDS.items() for f in word.forms}
_COMPOUNDS: dict[tuple[str, str], str] = {tuple(f.split("-")): f for f in _FORMS if "-" in f and f.count("-") == 1}  # type: ignore[misc]


def word_of(form: str) -> str | None:
    """The canonical word of ``form`` ("legs" for "feet", "top" for "table top"/"table-top"); None when unknown."""
    f = str(form).lower().strip().replace(" ", "-")
    if f in _FORMS:
        return _FORMS[f]
    # a plural or singular the table does not list ("armrest" / "armrests", "shelf" / "shelves")
    for cand in (f + "s", f + "es", f[:-1], f[:-2], f[:-3] + "y", f[:-3] + "f", f[:-3] + "fe"):
        if len(cand) > 2 and cand in _FORMS and same_word(cand, f):
            return _FORMS[cand]
    return None


def join_compounds(tokens: list[str]) -> list[str]:
    """Two-word forms joined into one token: ``["table", "top"]`` -> ``["table-top"]``."""
    out: list[str] = []
    i = 0
    while i < len(tokens):
        if i + 1 < len(tokens) and (tokens[i], tokens[i + 1]) in _COMPOUNDS:
            out.append(_COMPOUNDS[(tokens[i], tokens[i + 1])])
            i += 2
        else:
            out.append(tokens[i])
            i += 1
    return out


def join_compounds_text(text: str) -> str:
    """``text`` with its two-word part forms joined by a hyphen ("a marble table top" -> "a marble
    table-top"), everything else kept as it was."""
    import re

    out = str(text)
    for (first, second), joined in _COMPOUNDS.items():
        out = re.sub(rf"\b{re.escape(first)}\s+{re.escape(second)}\b", joined, out, flags=re.IGNORECASE)
    return out


def kind_of(tokens: list[str], material: Callable[[str], bool] = lambda t: False) -> str | None:
    """The kind a prompt is about: its object noun's ("a lamp"; a word ``material`` reads as a
    material, the "glass" of "green glass", names no object), else the kind whose words the prompt
    uses most (one kind only; a tie: None)."""
    for t in tokens:
        if t in NOUNS and not material(t):
            return NOUNS[t]
    words = {word_of(t) for t in tokens} - {None}
    if not words:
        return None
    counts = {k: len(words & set(ws)) for k, ws in WORD_KINDS.items()}
    best = max(counts.values())
    top = [k for k, c in counts.items() if c == best]
    return top[0] if best > 0 and len(top) == 1 else None


def score(word: str, e: Evidence, all_: list[Evidence], kind: str | None) -> tuple[float, str]:
    """``word``'s score of group ``e`` in [0, 1] and why: the kind's own scorer, else the general
    one; with no kind, the best over every scorer of the word."""
    entry = WORDS[word]
    if kind is not None:
        fn, why = entry.scorers.get(kind, entry.scorers[_ANY])
        return float(np.clip(fn(e, all_), 0.0, 1.0)), why
    best = (0.0, entry.scorers[_ANY][1])
    for fn, why in entry.scorers.values():
        s = float(np.clip(fn(e, all_), 0.0, 1.0))
        if s > best[0]:
            best = (s, why)
    return best
