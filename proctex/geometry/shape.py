"""The shape record and the procedural-model interface.

A procedural model is a black box ``params -> mesh`` (docs/architecture.md). Built-in models additionally
return, per vertex, canonical coordinates and a semantic part label, our ground truth for
correspondence (docs/correspondence.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from proctex.params import ParamSpace
from .primitives import Part


@dataclass
class Shape:
    """A triangle mesh whose connected components (by shared vertex index) are its parts.

    Attributes:
        vertices: (n, 3) float64.
        faces: (m, 3) int64.
        canonical: (n, 3) float64 canonical coordinates, or None (shapes not from a built-in model).
        labels: (n,) int32 index into ``label_names`` per vertex, or None.
        label_names: semantic part labels ("leg", "seat", ...).
        params: the validated parameters the shape was generated from ({} when unknown).
        source: where it came from (model name or file path), informational.
        corner_uv: (m, 3, 2) float64 UVs per face corner that the source made (a Blender graph's UV
            map), or None. Used as the template's UVs only where the user asks.
        face_source: (m,) int64 the node that made each face (a ``.blend`` model's producing node,
            :mod:`proctex.sources.provenance`; 0: none), or None. With ``canonical`` (each node's own
            box coordinates) it is the canonical truth of a ``.blend`` family: a point's counterpart
            is looked up only among faces of the same node. For measuring only.
        derived: what is computed from the shape once and kept with it (not an argument: a new
            shape, ``dataclasses.replace`` included, starts empty; left out of comparisons and
            ``repr``): ``"parts"``, its segmentation (:func:`proctex.geometry.parts.parts_of`), and in a
            build ``"assignment"``, its parts assigned to a template (``proctex.build.pairs``), each
            with the arrays it was computed from, so a replaced array is seen.
    """

    vertices: np.ndarray
    faces: np.ndarray
    canonical: np.ndarray | None = None
    labels: np.ndarray | None = None
    label_names: tuple[str, ...] = ()
    params: dict[str, Any] = field(default_factory=dict)
    source: str = ""
    corner_uv: np.ndarray | None = None
    face_source: np.ndarray | None = None
    derived: dict[str, Any] = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.vertices = np.ascontiguousarray(self.vertices, dtype=np.float64)
        self.faces = np.ascontiguousarray(self.faces, dtype=np.int64)
        if self.vertices.ndim != 2 or self.vertices.shape[1] != 3:
            raise ValueError(f"vertices must be (n, 3), got {self.vertices.shape}")
        if self.faces.ndim != 2 or self.faces.shape[1] != 3:
            raise ValueError(f"faces must be (m, 3), got {self.faces.shape}")
        n = len(self.vertices)
        if self.faces.size and (self.faces.min() < 0 or self.faces.max() >= n):
            raise ValueError(f"face indices must be in [0, {n}), got range [{self.faces.min()}, {self.faces.max()}]")
        if self.canonical is not None:
            self.canonical = np.ascontiguousarray(self.canonical, dtype=np.float64)
            if self.canonical.shape != (n, 3):
                raise ValueError(f"canonical must be ({n}, 3), got {self.canonical.shape}")
        if self.face_source is not None:
            self.face_source = np.ascontiguousarray(self.face_source, dtype=np.int64)
            if self.face_source.shape != (len(self.faces),):
                raise ValueError(f"face_source must be ({len(self.faces)},), got {self.face_source.shape}")
        if self.labels is not None:
            self.labels = np.ascontiguousarray(self.labels, dtype=np.int32)
            if self.labels.shape != (n,):
                raise ValueError(f"labels must be ({n},), got {self.labels.shape}")
            if n and (self.labels.min() < 0 or self.labels.max() >= len(self.label_names)):
                raise ValueError("labels index outside label_names")
        if self.corner_uv is not None:
            self.corner_uv = np.ascontiguousarray(self.corner_uv, dtype=np.float64)
            if self.corner_uv.shape != (len(self.faces), 3, 2) or not np.isfinite(self.corner_uv).all():
                raise ValueError(f"corner_uv must be finite ({len(self.faces)}, 3, 2), got {self.corner_uv.shape}")

    @property
    def n_vertices(self) -> int:
        return len(self.vertices)

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    def vertex_label_names(self) -> np.ndarray:
        """(n,) object array of label strings (requires labels)."""
        if self.labels is None:
            raise ValueError("shape has no semantic labels")
        return np.asarray(self.label_names, dtype=object)[self.labels]


def split_by_face_parts(faces: np.ndarray, face_part: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """Give faces of different parts their own vertices, so that connected components (the parts of
    a :class:`Shape`) never span two of ``face_part``'s values.

    Args:
        faces: (m, 3) int vertex indices; face_part: (m,) int part per face; n_vertices: n.

    Returns:
        ``(faces (m, 3) int64 new indices, source (k,) int64 old vertex of each new one)``: one new
        vertex per (vertex, part) pair in use, in vertex order; unused vertices are dropped.
    """
    faces = np.asarray(faces, dtype=np.int64)
    face_part = np.asarray(face_part, dtype=np.int64)
    if faces.ndim != 2 or faces.shape[1] != 3 or face_part.shape != (len(faces),):
        raise ValueError(f"faces must be (m, 3) and face_part (m,), got {faces.shape} and {face_part.shape}")
    if faces.size and (faces.min() < 0 or faces.max() >= n_vertices):
        raise ValueError(f"face indices must be in [0, {n_vertices})")
    if len(faces) == 0:
        return faces.reshape(0, 3), np.zeros(0, dtype=np.int64)
    _, part = np.unique(face_part, return_inverse=True)
    keys = faces * (int(part.max()) + 1) + part[:, None]  # (vertex, part) as one integer, vertex-major
    unique, inverse = np.unique(keys, return_inverse=True)
    return inverse.reshape(faces.shape).astype(np.int64), unique // (int(part.max()) + 1)


class ShapeBuilder:
    """Accumulates labelled parts into one :class:`Shape`."""

    def __init__(self) -> None:
        self._parts: list[tuple[Part, str]] = []

    def add(self, part: Part, label: str) -> "ShapeBuilder":
        if not label:
            raise ValueError("every part needs a semantic label")
        self._parts.append((part, label))
        return self

    @property
    def n_parts(self) -> int:
        return len(self._parts)

    def build(self, params: Mapping[str, Any] | None = None, source: str = "") -> Shape:
        if not self._parts:
            raise ValueError("a shape needs at least one part")
        names: list[str] = []
        for _, label in self._parts:
            if label not in names:
                names.append(label)
        verts, faces, canon, labels = [], [], [], []
        offset = 0
        for part, label in self._parts:
            verts.append(part.vertices)
            faces.append(part.faces + offset)
            canon.append(part.canonical)
            labels.append(np.full(len(part.vertices), names.index(label), dtype=np.int32))
            offset += len(part.vertices)
        return Shape(
            np.concatenate(verts),
            np.concatenate(faces),
            np.concatenate(canon),
            np.concatenate(labels),
            tuple(names),
            dict(params or {}),
            source,
        )


TESSELLATIONS = ("fixed", "adaptive")


def check_tessellation(tessellation: Any) -> str:
    """``tessellation`` if it is ``"fixed"`` or ``"adaptive"``, else ``ValueError`` naming the two."""
    if not isinstance(tessellation, str) or tessellation not in TESSELLATIONS:
        raise ValueError(f"tessellation must be one of {list(TESSELLATIONS)}, got {tessellation!r}")
    return tessellation


class ProceduralModel:
    """A named family: parameter specs + ``generate(params) -> Shape``.

    Subclasses set ``name``, ``description``, ``space`` and implement ``_build(params)`` returning a
    :class:`Shape` (usually via :class:`ShapeBuilder`). Built-in models also implement
    ``expected_counts(params) -> (parts, groups)``: the number of connected components and of part
    groups (repeated or mirrored parts share a group) that the parameters imply.

    ``tessellation`` (not a parameter of the family, a property of the generator) is ``"fixed"``
    (every part keeps its mesh connectivity whatever the parameters) or ``"adaptive"`` (segment
    counts follow the parts' sizes, ``max(minimum, round(length / edge_length))``, like a real
    exporter's resolution setting). Both give the same surfaces and the same canonical coordinates
    for the same parameters, up to the piecewise-linear chord error.

    ``generate`` is deterministic: equal parameters give identical arrays.
    """

    name: str = ""
    description: str = ""
    space: ParamSpace = ParamSpace(())
    builtin: bool = False
    tessellation: str = "fixed"
    edge_length: float = 0.0  # target edge length (m) of the adaptive tessellation; built-in models set it

    def __init__(self, tessellation: str = "fixed") -> None:
        self.tessellation = check_tessellation(tessellation)

    @property
    def adaptive(self) -> bool:
        """Whether segment counts follow the parts' sizes."""
        return self.tessellation == "adaptive"

    @property
    def target_edge(self) -> float | None:
        """``edge_length`` (m) in adaptive mode, ``None`` in fixed mode (the builders' convention)."""
        if not self.adaptive:
            return None
        if not self.edge_length > 0:
            raise ValueError(f"model {self.name!r} has no edge_length for adaptive tessellation")
        return float(self.edge_length)

    def generate(self, params: Mapping[str, Any] | None = None) -> Shape:
        """Validate ``params`` (missing ones take defaults) and build the shape."""
        p = self.space.validate(params)
        shape = self._build(p)
        if not isinstance(shape, Shape):
            raise ValueError(f"model {self.name!r} returned {type(shape).__name__}, expected Shape")
        shape.params = p
        shape.source = self.name
        if not np.all(np.isfinite(shape.vertices)):
            raise ValueError(f"model {self.name!r} produced non-finite vertices for {p}")
        return shape

    def _build(self, params: dict[str, Any]) -> Shape:  # pragma: no cover - interface
        raise NotImplementedError

    def expected_counts(self, params: Mapping[str, Any] | None = None) -> tuple[int, int]:
        raise NotImplementedError(f"model {self.name!r} does not declare expected counts")

    def describe(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "description": self.description,
            "builtin": self.builtin,
            "tessellation": self.tessellation,
            "params": self.space.to_list(),
        }
