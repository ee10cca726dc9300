"""A Blender Geometry Nodes model as a family source: the ``.blend`` file is a black box whose
modifier inputs are the family's parameters (issue 19, first slice).

Blender's Python (``bpy`` from PyPI) needs numpy < 2, so it runs in its own environment
(``.venv-blender``, made by ``make blender``) and its own long-lived process, which opens the file
once (:mod:`proctex.sources.blender_server`, spoken to over a pipe, one JSON line per request).
:class:`BlenderModel` is a :class:`~proctex.geometry.shape.ProceduralModel`: its parameter space is
read from the modifier's exposed inputs (float / int / bool / menu, with the node group's
min / max / default), which ``bounds`` may narrow and ``pins`` may fix; ``generate(params)`` sets
the inputs, evaluates the depsgraph headless and returns the evaluated, triangulated mesh in the
object's own coordinates (where the object stands in the file is not part of the shape; the add-on
sends meshes in the same frame). A named face / point / corner attribute (``parts``) may define the parts instead of
the mesh's connectivity, and a UV map the graph makes (``uv``) may travel with the shape
(:attr:`Shape.corner_uv`), for the template's UVs where the user asks.
"""

from __future__ import annotations

import base64
import json
import os
import select
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from proctex.geometry.shape import ProceduralModel, Shape, split_by_face_parts
from proctex.params import ParamSpace, ParamSpec, choice, continuous, integer

SERVER = Path(__file__).with_name("blender_server.py")
REPO = Path(__file__).resolve().parents[2]
#: A .blend larger than this gets progress lines while its Blender process opens it.
SLOW_FILE_BYTES = 20_000_000
UNBOUNDED = 1e6  # a Blender input range wider than this is "no range given": held at the file's value unless bounded
MAX_PRODUCERS = 20_000  # producers read from the Blender process (it instruments no more than this)
FIXED = "held at the file's value"  # the description of an input a build does not vary


def blender_python() -> str | None:
    """The Python that has ``bpy``: ``$PROCTEX_BLENDER_PYTHON``, else ``.venv-blender/bin/python`` in
    the repository; None when neither exists."""
    env = os.environ.get("PROCTEX_BLENDER_PYTHON")
    if env:
        return env
    local = REPO / ".venv-blender" / "bin" / "python"
    return str(local) if local.exists() else None


@dataclass
class Evaluated:
    """One evaluated mesh from Blender.

    Attributes:
        vertices: (n, 3) float64 object coordinates; faces: (m, 3) int64 triangles.
        seconds: Blender's own time for the evaluation.
        attributes: ``(name, domain, type)`` of every named attribute the mesh carries.
        corner_uv: (m, 3, 2) float64 UVs of the requested UV map, or None.
        face_parts: (m,) int64 part per triangle from the requested attribute (values renumbered
            0..k-1 in sorted order), or None.
        objects: how many objects Blender evaluated for it (the model and what its graph reads).
        face_source: (m,) int64 producer id per triangle (0: none; :mod:`proctex.sources.provenance`),
            or None when the tree was evaluated plain.
        face_instance: (m,) int64 realized instance index per triangle (-1: none), or None.
        canonical: (n, 3) float64 each vertex in its producer's own bounding box (NaN: none), or None.
    """

    vertices: np.ndarray
    faces: np.ndarray
    seconds: float
    attributes: list[tuple[str, str, str]]
    corner_uv: np.ndarray | None = None
    face_parts: np.ndarray | None = None
    objects: int = 1
    face_source: np.ndarray | None = None
    face_instance: np.ndarray | None = None
    canonical: np.ndarray | None = None


class BlenderSession:
    """One Blender process with one ``.blend`` file open (:mod:`proctex.sources.blender_server`).

    The process is the only thing that can crash: a request it dies on, or does not answer within
    ``timeout`` seconds, is a ``ValueError`` (the process is killed), and the next request starts a
    fresh process that opens the file again (:attr:`restarts` counts them)."""

    def __init__(self, file: str | os.PathLike, obj: str, modifier: str = "GeometryNodes", python: str | None = None, timeout: float = 120.0) -> None:
        self.file = str(Path(file).resolve())
        if not Path(self.file).is_file():
            raise ValueError(f"{file}: no such .blend file")
        self.python = python or blender_python()
        if not self.python:
            raise ValueError("no Python with bpy: run `make blender` (it makes .venv-blender) or set PROCTEX_BLENDER_PYTHON")
        self.obj, self.modifier, self.timeout = obj, modifier, timeout
        self.restarts = -1
        self.proc: subprocess.Popen | None = None
        #: the nodes that make geometry (:func:`proctex.sources.blender_server.instrument`), why there
        #: are none where the tree could not be instrumented, and the model's own names
        self.producers: list[dict[str, Any]] = []
        self.provenance_error: str | None = None
        self.tree, self.object_name = "", obj
        self.inputs: list[dict[str, Any]] = self._start()

    def _start(self) -> list[dict[str, Any]]:
        self.restarts += 1
        size = Path(self.file).stat().st_size
        if size > SLOW_FILE_BYTES:  # a scene file can take tens of seconds to open: say so first
            print(f"blender: opening {Path(self.file).name} ({size / 1e6:.0f} MB) in a Blender process ...", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        self.proc = subprocess.Popen([self.python, str(SERVER)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, bufsize=1)
        try:
            opened = self._send({"op": "open", "file": self.file, "object": self.obj, "modifier": self.modifier})
            inputs = opened["inputs"]
        except ValueError:
            self._kill()  # a file Blender cannot open (or without the object): no process is left behind
            raise
        producers = opened.get("producers")
        self.producers = producers[:MAX_PRODUCERS] if isinstance(producers, list) else []
        self.provenance_error = opened.get("provenance_error")
        self.tree, self.object_name = str(opened.get("tree") or "")[:256], str(opened.get("object") or self.obj)[:256]
        self.open_seconds = time.perf_counter() - t0
        if size > SLOW_FILE_BYTES or self.open_seconds > 5.0:
            print(f"blender: {Path(self.file).name} open in {self.open_seconds:.1f} s ({len(inputs)} inputs)", file=sys.stderr, flush=True)
        return inputs

    def request(self, req: dict[str, Any]) -> dict[str, Any]:
        """Send one request; its answer, or ``ValueError`` with Blender's error, or when the process
        died or did not answer within ``timeout`` seconds (a dead process is started again first)."""
        if self.proc is None or self.proc.poll() is not None:
            inputs = self._start()
            if inputs != self.inputs:
                raise ValueError(f"{self.file} changed its inputs since it was opened; build the family again")
        return self._send(req)

    def _send(self, req: dict[str, Any]) -> dict[str, Any]:
        proc = self.proc
        try:
            proc.stdin.write(json.dumps(req) + "\n")
            proc.stdin.flush()
        except (BrokenPipeError, OSError):
            pass  # it died already: the read below says how
        ready, _, _ = select.select([proc.stdout], [], [], self.timeout)
        if not ready:
            self._kill()
            raise ValueError(f"Blender did not answer {req.get('op')!r} within {self.timeout:g} s ({self.file}); the process was stopped")
        line = proc.stdout.readline()
        if not line:
            code = proc.wait()
            how = f"signal {-code}" if code < 0 else f"exit status {code}"
            raise ValueError(f"the Blender process for {self.file} ended ({how}) during {req.get('op')!r} {json.dumps(req.get('params', {}))[:300]}")
        data = json.loads(line)
        if "error" in data:
            raise ValueError(f"{self.file}: {data['error']}")
        return data

    def _kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()

    def generate(self, params: Mapping[str, Any], uv: str | None = None, parts: str | None = None, plain: bool = False) -> Evaluated:
        """The evaluated mesh for ``params``, with the UV map ``uv`` and the part attribute ``parts``
        where named (:class:`Evaluated`); with its faces' provenance unless ``plain`` (the tree as the
        file has it, evaluated without instrumentation)."""
        out = self.request({"op": "generate", "params": dict(params), "uv": uv, "parts": parts, "plain": bool(plain)})
        m, n = int(out["m"]), int(out["n"])

        def array(key: str, dtype: Any, shape: tuple[int, ...]) -> np.ndarray | None:
            if key not in out:
                return None
            return np.frombuffer(base64.b64decode(out[key]), dtype=dtype).reshape(shape).copy()

        return Evaluated(
            array("vertices", np.float64, (-1, 3)),
            array("faces", np.int64, (m, 3)),
            float(out["seconds"]),
            [tuple(a) for a in out.get("attributes", [])],
            array("corner_uv", np.float64, (m, 3, 2)),
            array("face_parts", np.int64, (m,)),
            int(out.get("objects", 1)),
            array("face_source", np.int64, (m,)),
            array("face_instance", np.int64, (m,)),
            array("canonical", np.float64, (n, 3)),
        )

    def close(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            try:
                self.proc.stdin.write(json.dumps({"op": "quit"}) + "\n")
                self.proc.stdin.flush()
                self.proc.wait(timeout=10)
            except (OSError, subprocess.TimeoutExpired, ValueError):
                self._kill()

    def __del__(self) -> None:  # pragma: no cover - best effort at garbage collection
        try:
            self.close()
        except Exception:
            pass


def _f32(value: Any) -> float:
    """A Blender (single precision) number as the decimal it was typed as: 0.2, not 0.20000000298."""
    return float(f"{float(value):.7g}")


@dataclass
class InputPlan:
    """How a build treats a modifier's inputs (:func:`input_specs`).

    Attributes:
        space: the parameter space: inputs that vary, and inputs held at the file's value as
            one-value parameters (a range of one value, or a choice of one option, described as
            :data:`FIXED`), so every input is listed where parameters are shown.
        pins: the values the config pins (not in the space).
        fixed: ``{name: file value}`` of the inputs held at the file's value, and ``why`` each is.
        clamped: ``{name: (file value, low, high)}`` for file values outside the range they vary in
            (their default is clamped into it).
    """

    space: ParamSpace
    pins: dict[str, Any]
    fixed: dict[str, Any] = field(default_factory=dict)
    why: dict[str, str] = field(default_factory=dict)
    clamped: dict[str, tuple[Any, float, float]] = field(default_factory=dict)

    def notes(self) -> list[str]:
        """One line per fixed input and per clamp, for the build's log and record."""
        out = [f"{name!r} {FIXED} ({value!r}): {self.why[name]}" for name, value in self.fixed.items()]
        out += [f"{name!r}: the file's value {v!r} lies outside [{lo:g}, {hi:g}]; its default is clamped to {min(max(float(v), lo), hi):g}" for name, (v, lo, hi) in self.clamped.items()]
        return out


def file_value(s: Mapping[str, Any]) -> Any:
    """What the modifier holds for input ``s`` in the file (the node group's default when the
    Blender side did not say)."""
    value = s.get("value", s.get("default"))
    if s["type"] == "float":
        return _f32(value if value is not None else 0.0)
    if s["type"] == "int":
        return int(value if value is not None else 0)
    if s["type"] == "bool":
        return bool(value)
    return value


def input_specs(inputs: list[dict[str, Any]], bounds: Mapping[str, Any] | None = None, pins: Mapping[str, Any] | None = None, listed: Any = None) -> InputPlan:
    """The parameter space of a modifier's inputs (:class:`InputPlan`).

    ``bounds`` ``{name: [low, high]}`` narrow float / int ranges (within Blender's); ``pins`` fix
    inputs (they leave the space). ``listed``: the inputs a params spec or ``[source.params]``
    names (None: no list). Listed inputs vary; with a list, every other input is held at the file's
    value. Without one, inputs whose Blender range is usable vary and the rest are held at the
    file's value. A float or int that is to vary needs a usable range (Blender's, or its bounds).
    Defaults are the file's values (clamped into the range, :attr:`InputPlan.clamped`). A space in
    which nothing varies is a ``ValueError`` naming the inputs that could vary."""
    bounds, pins = dict(bounds or {}), dict(pins or {})
    names = {s["name"] for s in inputs}
    for key in list(bounds) + list(pins):
        if key not in names:
            raise ValueError(f"no input {key!r}; the modifier's inputs are {sorted(names)}")
    wanted = None if listed is None else set(listed) | set(bounds)
    plan = InputPlan(ParamSpace(()), pins)
    specs: list[ParamSpec] = []
    unranged: list[str] = []
    for s in inputs:
        name = s["name"]
        if name in pins or s["type"] not in ("float", "int", "bool", "menu") or (s["type"] == "menu" and not s.get("options")):
            continue
        value = file_value(s)
        vary, why = True, ""
        if wanted is not None and name not in wanted:
            vary, why = False, "the spec does not list it"
        if s["type"] in ("float", "int"):
            lo, hi = _f32(s["min"]), _f32(s["max"])
            if name in bounds:
                b_lo, b_hi = (float(x) for x in bounds[name])
                if not (lo <= b_lo <= b_hi <= hi):
                    raise ValueError(f"bounds for {name!r} must lie within Blender's [{lo:g}, {hi:g}], got [{b_lo:g}, {b_hi:g}]")
                lo, hi = b_lo, b_hi
            if vary and max(abs(lo), abs(hi)) > UNBOUNDED:
                vary, why = False, f"no usable range in Blender ([{lo:g}, {hi:g}])"
                unranged.append(name)
            if not vary:
                plan.fixed[name], plan.why[name] = value, why
                specs.append(continuous(name, value, value, value, description=FIXED) if s["type"] == "float" else integer(name, value, value, value, description=FIXED))
                continue
            default = min(max(value, lo), hi)
            if default != value:
                plan.clamped[name] = (value, lo, hi)
            specs.append(continuous(name, lo, hi, default) if s["type"] == "float" else integer(name, int(lo), int(hi), int(round(default))))
        else:
            options = (False, True) if s["type"] == "bool" else tuple(s["options"])
            if value not in options:
                value = options[0]
            if not vary:
                plan.fixed[name], plan.why[name] = value, why
                options = (value,)
            specs.append(choice(name, options, value, description=FIXED if not vary else ""))
    plan.space = ParamSpace(tuple(specs))
    if specs and all(s.name in plan.fixed for s in specs):
        could = [s["name"] for s in inputs if s["name"] not in pins and s["type"] in ("float", "int", "bool", "menu")]
        how = "give their ranges in a params spec (--params-spec FILE.json) or [source.params] name = [low, high]" if unranged else "list them in the params spec or [source.params]"
        raise ValueError(f"no input varies ({len(could)} held at the file's values): inputs that could vary: {', '.join(repr(n) for n in could[:20])}{' ...' if len(could) > 20 else ''}; {how}")
    return plan


class BlenderModel(ProceduralModel):
    """A family from a ``.blend`` file's Geometry Nodes modifier (module docstring).

    ``listed``: the inputs a params spec or ``[source.params]`` names (:func:`input_specs`); the
    others are held at the file's values. Where the file's node tree names its parts (frames, node
    groups, renamed nodes: :mod:`proctex.sources.provenance`), each shape's parts carry those names
    as their labels; :attr:`last_names` holds the last shape's (with the other names each part
    carries and the share of its area whose faces have a producer)."""

    def __init__(
        self,
        file: str | os.PathLike,
        obj: str,
        modifier: str = "GeometryNodes",
        bounds: Mapping[str, Any] | None = None,
        pins: Mapping[str, Any] | None = None,
        python: str | None = None,
        uv: str | None = None,
        parts: str | None = None,
        listed: Any = None,
    ) -> None:
        from proctex.sources.provenance import model_words, producer_names

        super().__init__("adaptive")
        self.session = BlenderSession(file, obj, modifier, python=python)
        self.uv, self.parts = uv, parts
        self.attributes: list[tuple[str, str, str]] = []
        self.name = f"blender:{Path(file).stem}/{obj}"
        self.description = f"Geometry Nodes modifier {modifier!r} of {obj!r} in {Path(file).name}"
        self.plan = input_specs(self.session.inputs, bounds, pins, listed)
        self.space, self.pins = self.plan.space, self.plan.pins
        self.file_values = {s["name"]: file_value(s) for s in self.session.inputs if s["type"] in ("float", "int", "bool", "menu")}
        self.whole = model_words(self.session.object_name, self.session.tree)
        self.producer_names = producer_names(self.session.producers, self.whole)
        self.last_seconds = 0.0
        self.last_names = None

    def _build(self, params: Mapping[str, Any]) -> Shape:
        from proctex.geometry.parts import connected_parts
        from proctex.geometry.surface import triangle_areas
        from proctex.sources.provenance import part_names

        given = {k: (v.item() if hasattr(v, "item") else v) for k, v in params.items()}
        if any(s.when or s.unless for s in self.space.specs):  # an input that does not act keeps the file's value exactly
            active = set(self.space.active(given))
            given = {k: (v if k in active or k not in self.file_values else self.file_values[k]) for k, v in given.items()}
        values = {**self.pins, **given}
        out = self.session.generate(values, uv=self.uv, parts=self.parts)
        self.last_seconds, self.attributes = out.seconds, out.attributes
        if len(out.faces) == 0:
            raise ValueError(f"{self.name}: the evaluated mesh has no faces for {values}")
        vertices, faces, face_source, canonical = out.vertices, out.faces, out.face_source, out.canonical
        if out.face_parts is not None:  # the graph's parts, not its connectivity
            faces, source = split_by_face_parts(faces, out.face_parts, len(vertices))
            vertices = vertices[source]
            canonical = canonical[source] if canonical is not None else None
        labels, label_names = None, ()
        self.last_names = None
        if face_source is not None and any(n.name for n in self.producer_names.values()):
            face_part, _, count = connected_parts(faces, len(vertices))
            named = part_names(face_source, face_part, triangle_areas(vertices, faces), self.producer_names, count)
            self.last_names = named
            label_names = tuple(sorted(set(named.names) | {""}))
            index = {name: i for i, name in enumerate(label_names)}
            labels = np.zeros(len(vertices), dtype=np.int32)  # unreferenced vertices: "" (no name)
            labels[faces.reshape(-1)] = np.repeat([index[named.names[p]] for p in face_part.tolist()], 3)
        # Each producing node's own box coordinates and the node of each face: the canonical truth
        # (measuring only; never trained, selected or fitted on).
        truth = {"canonical": canonical, "face_source": face_source} if face_source is not None and canonical is not None else {}
        return Shape(vertices, faces, source=self.session.file, corner_uv=out.corner_uv, labels=labels, label_names=label_names, **truth)

    @property
    def has_canonical(self) -> bool:
        """Whether its shapes carry canonical truth (the node tree was instrumented)."""
        return self.session.provenance_error is None and bool(self.session.producers)

    def close(self) -> None:
        self.session.close()


if __name__ == "__main__":  # pragma: no cover
    print(blender_python() or "no Python with bpy", file=sys.stderr)


#: The settings of a ``blender`` source: ``parts`` names an attribute whose values are the parts
#: (instead of the mesh's connectivity); ``uv`` names a UV map the graph makes, kept as the
#: template's UVs (each group's representative keeps its own layout).
BLENDER_KEYS = ("file", "object", "modifier", "pins", "parts", "uv")
