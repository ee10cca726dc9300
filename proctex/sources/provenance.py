"""Part names from a Geometry Nodes tree: where each face came from, and what the author called it.

The Blender side (:mod:`proctex.sources.blender_server`) evaluates an instrumented copy of the
model's node tree in which every node that makes geometry (a *producer*: mesh and curve
primitives, Object / Collection Info, Curve to Mesh, Volume to Mesh, Fill Curve, Convex Hull,
import nodes, the root's Group Input) stores its id on what it makes. The nearest producer to a face
wins: a value a curve carries flows on to the mesh built from it unless that mesh's own producer
(Curve to Mesh) overrides it. Each producer comes with where it sits: its own label and name, the
frames around it (``node.parent``, innermost first), the node groups it is nested in (innermost
first) and, for Info nodes, the object or collection it reads.

A producer's *name* is the most specific meaningful label among, in order: the node's own label,
its name when the author renamed it, the object or collection an Info node reads, its frames from
the innermost out, then each node group it is nested in from the innermost out (the group node's
label, else its tree's name) followed by the frames that group node sits in. A label is not meaningful when it

- is a default ("Cube.001" for a Cube node, "Frame.006", "NodeGroup", an object called "Plane");
- has no words left once numbers and the model's own words (the object's and the root tree's
  names: "Cabinet" in "CabinetBoardRight" of an object "Cabinet", which is named "Board Right") are
  dropped;
- labels a computation rather than a part: it starts with a verb of geometry processing ("Set To
  Zero Z Axis", "Center Z at Origin", "Spawn Leaves", "Determine Trunk Area", "Meshing Curve"), or it
  holds a preposition that ties a step to a target ("at", "to", "into", "onto", "by", "from", "per",
  "via", "based"): "Ever Green Based On Surface". Part names are noun phrases ("Back Rest", "Left
  Arm", "Dividing Boards"); a gerund alone is not taken as a verb, since parts are named that way
  too ("Sliding Door").

Names are untrusted input: each is cut to :data:`MAX_NAME` characters and :data:`MAX_WORDS`
words, and a part lists at most :data:`MAX_NAMES` names. Names are for painting and reading only:
they never train, select or fit anything.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from proctex.texture.painters.names import MAX_WORDS, NOT_PARTS, QUALIFIERS, label_words, matchable_words, same_word

__all__ = [
    "label_words",
    "matchable_words",
    "same_word",
    "QUALIFIERS",
    "NOT_PARTS",
    "ProducerName",
    "PartNames",
    "producer_names",
    "part_names",
    "model_words",
    "is_default",
    "is_computation",
    "meaningful",
]

MAX_NAME = 64
MAX_NAMES = 16

#: Verbs that start a label of a computation rather than of a part.
VERBS = frozenset(
    """
add adjust align apply bevel calculate calculating capture center centre clamp combine compute computing convert create
delete determine determining distribute extrude fill fix flatten flip generate get instance instancing invert join make
map merge mesh meshing mirror move normalize normalise offset place position raise randomize randomise realize realise
remove resample rotate sample scale select separate set shift smooth snap spawn spawning split store subdivide switch
transform translate trim
""".split()
)
#: Prepositions that tie a step to its target ("Center Z at Origin").
PREPOSITIONS = frozenset("at to into onto by from per via based".split())
#: Blender's default names of nodes it makes and of objects and collections in a new file.
DEFAULT_NAMES = frozenset(
    {
        "frame",
        "reroute",
        "nodegroup",
        "node group",
        "group",
        "geometry nodes",
        "geometrynodes",
        "group input",
        "group output",
        "cube",
        "plane",
        "circle",
        "cylinder",
        "sphere",
        "icosphere",
        "uv sphere",
        "uvsphere",
        "cone",
        "torus",
        "monkey",
        "suzanne",
        "empty",
        "camera",
        "light",
        "lamp",
        "text",
        "beziercurve",
        "bezier curve",
        "beziercircle",
        "nurbspath",
        "nurbscurve",
        "collection",
        "scene",
        "grid",
        "mesh",
        "line",
        "point",
        "points",
        "curve",
    }
)


def is_default(label: str, bl_label: str = "") -> bool:
    """Whether ``label`` is a name Blender gave (``"Cube.001"`` for a Cube node whose ``bl_label``
    is "Cube", ``"Frame.006"``, ``"Plane"``), not one an author typed."""
    base = re.sub(r"\.\d+$", "", str(label)).strip().lower()
    if not base:
        return True
    squashed = base.replace(" ", "").replace("_", "")
    if bl_label and base == bl_label.strip().lower():
        return True
    return base in DEFAULT_NAMES or squashed in DEFAULT_NAMES


def is_computation(words: Sequence[str]) -> bool:
    """Whether a label's words name a step of the computation rather than a part (module
    docstring): a leading verb, or a preposition tying the step to a target."""
    low = [w.lower() for w in words]
    return bool(low) and (low[0] in VERBS or any(w in PREPOSITIONS for w in low))


def model_words(*names: str) -> frozenset[str]:
    """The lower-case words of the model's own names (its object, its root tree), singular and
    plural: a label made of them names the whole model, not a part."""
    out: set[str] = set()
    for name in names:
        for w in label_words(name or ""):
            w = w.lower()
            out.update({w, w[:-1] if w.endswith("s") else w + "s"})
    return frozenset(out)


def meaningful(label: str, bl_label: str, whole: frozenset[str]) -> tuple[str, str]:
    """``(name, "")`` when ``label`` is a part name (its words joined by spaces, cut to
    :data:`MAX_NAME` characters), else ``("", why it was dropped)``."""
    label = str(label or "")
    if not label.strip():
        return "", ""
    if is_default(label, bl_label):
        return "", "a default name"
    words = label_words(label)
    if not words:
        return "", "no words"
    if is_computation(words):
        return "", "labels a computation"
    own = [w for w in words if w.lower() not in whole]  # "Cabinet Board Right" of a cabinet: "Board Right"
    if all(w.lower() in NOT_PARTS for w in own):
        return "", "names the whole model"
    return " ".join(own[:MAX_WORDS])[:MAX_NAME], ""


@dataclass(frozen=True)
class ProducerName:
    """What one producer is called.

    Attributes:
        id: the producer id (>= 1).
        name: its part name ("" when no label around it is meaningful).
        where: what gave the name ("node label", "node name", "object", "frame", "group").
        dropped: ``(label, why)`` for each label nearer the node that was passed over.
        node: the producing node's name and type, for reading.
    """

    id: int
    name: str
    where: str
    dropped: tuple[tuple[str, str], ...] = ()
    node: str = ""


def _candidates(p: Mapping[str, Any]) -> Iterable[tuple[str, str, str]]:
    """``(label, its bl_label for the default test, where)`` in order of specificity."""
    yield str(p.get("label") or ""), "", "node label"
    yield str(p.get("node") or ""), str(p.get("bl_label") or ""), "node name"
    if p.get("data") and p.get("type") != "NodeGroupInput":
        yield str(p["data"]), "", "object"
    for f in p.get("frames") or []:
        yield str(f.get("label") or f.get("name") or ""), "Frame", "frame"
    for g in p.get("groups") or []:  # each group, then the frames its group node sits in, outwards
        yield str(g.get("label") or ""), "", "group"
        yield str(g.get("tree") or ""), "", "group"
        for f in g.get("frames") or []:
            yield str(f.get("label") or f.get("name") or ""), "Frame", "frame"


def producer_names(producers: Sequence[Mapping[str, Any]], whole: frozenset[str] = frozenset()) -> dict[int, ProducerName]:
    """Every producer's :class:`ProducerName` (module docstring), by id. ``whole``: the model's own
    words (:func:`model_words`). Malformed entries (not a mapping, no integer id) are skipped."""
    out: dict[int, ProducerName] = {}
    for p in producers:
        if not isinstance(p, Mapping) or not isinstance(p.get("id"), int) or isinstance(p.get("id"), bool):
            continue
        dropped: list[tuple[str, str]] = []
        name, where = "", ""
        for label, bl_label, kind in _candidates(p):
            got, why = meaningful(label, bl_label, whole)
            if got:
                name, where = got, kind
                break
            if why and label.strip():
                dropped.append((label[:MAX_NAME], why))
        out[int(p["id"])] = ProducerName(int(p["id"]), name, where, tuple(dropped), f"{str(p.get('node', ''))[:MAX_NAME]} ({str(p.get('type', ''))[:48]})")
    return out


@dataclass
class PartNames:
    """Names of the parts of one evaluated shape.

    Attributes:
        names: per part, its name: the name covering most of its area ("" for none).
        others: per part, the other names its faces carry, by area (at most :data:`MAX_NAMES`).
        covered: share of the shape's area whose faces have a producer (1.0 when every face does).
    """

    names: list[str]
    others: list[list[str]] = field(default_factory=list)
    covered: float = 1.0


def part_names(face_source: np.ndarray, face_part: np.ndarray, areas: np.ndarray, names: Mapping[int, ProducerName], n_parts: int) -> PartNames:
    """Each part's name from its faces' producers, weighted by area.

    Args:
        face_source: (m,) int producer id per face (0: none).
        face_part: (m,) int part per face, in ``[0, n_parts)``.
        areas: (m,) float face areas.
        names: :func:`producer_names`.
        n_parts: number of parts.
    """
    face_source = np.asarray(face_source, dtype=np.int64)
    face_part = np.asarray(face_part, dtype=np.int64)
    areas = np.asarray(areas, dtype=np.float64)
    if not (face_source.shape == face_part.shape == areas.shape) or face_source.ndim != 1:
        raise ValueError(f"face_source, face_part and areas must be (m,), got {face_source.shape}, {face_part.shape}, {areas.shape}")
    if len(face_part) and (face_part.min() < 0 or face_part.max() >= n_parts):
        raise ValueError("face_part outside [0, n_parts)")
    areas = np.where(np.isfinite(areas) & (areas > 0), areas, 0.0)
    label = np.array([names[s].name if s in names else "" for s in face_source.tolist()], dtype=object)
    total = float(areas.sum())
    covered = float(areas[face_source > 0].sum() / total) if total > 0 else float((face_source > 0).mean() if len(face_source) else 1.0)
    out = PartNames([""] * n_parts, [[] for _ in range(n_parts)], covered)
    order = np.argsort(face_part, kind="stable")
    bounds = np.searchsorted(face_part[order], np.arange(n_parts + 1))
    for p in range(n_parts):
        sel = order[bounds[p] : bounds[p + 1]]
        weights: dict[str, float] = {}
        for lab, a in zip(label[sel].tolist(), areas[sel].tolist()):
            if lab:
                weights[lab] = weights.get(lab, 0.0) + a + 1e-300
        ranked = sorted(weights, key=lambda k: (-weights[k], k))
        if ranked:
            out.names[p] = ranked[0]
            out.others[p] = ranked[1 : 1 + MAX_NAMES]
    return out
