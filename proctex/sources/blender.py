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
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from proctex.geometry.shape import ProceduralModel, Shape, split_by_face_parts
from proctex.params import ParamSpace, ParamSpec, choice, continuous, integer

SERVER = Path(__file__).with_name("blender_server.py")
REPO = Path(__file__).resolve().parents[2]
#: A .blend larger than this gets progress lines while its Blender process opens it.
SLOW_FILE_BYTES = 20_000_000
UNBOUNDED = 1e6  # a Blender input range wider than this is "no range given": the config must narrow it


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
    """

    vertices: np.ndarray
    faces: np.ndarray
    seconds: float
    attributes: list[tuple[str, str, str]]
    corner_uv: np.ndarray | None = None
    face_parts: np.ndarray | None = None
    objects: int = 1


class BlenderSession:
    """One Blender process with one ``.blend`` file open (:mod:`proctex.sources.blender_server`).

    The process is the only thing that can crash: a request it dies on, or does not answer within
    ``timeout`` seconds, is a ``ValueError`` (the process is killed), and the next request starts a
    fresh process that opens the file again (:attr:`restarts` counts them)."""

    def __init__(self, file: str | os.PathLike, obj: str, modifier: str = "GeometryNodes", python: str | None = None,
                 timeout: float = 120.0) -> None:
        self.file = str(Path(file).resolve())
        if not Path(self.file).is_file():
            raise ValueError(f"{file}: no such .blend file")
        self.python = python or blender_python()
        if not self.python:
            raise ValueError("no Python with bpy: run `make blender` (it makes .venv-blender) or set PROCTEX_BLENDER_PYTHON")
        self.obj, self.modifier, self.timeout = obj, modifier, timeout
        self.restarts = -1
        self.proc: subprocess.Popen | None = None
        self.inputs: list[dict[str, Any]] = self._start()

    def _start(self) -> list[dict[str, Any]]:
        self.restarts += 1
        size = Path(self.file).stat().st_size
        if size > SLOW_FILE_BYTES:  # a scene file can take tens of seconds to open: say so first
            print(f"blender: opening {Path(self.file).name} ({size / 1e6:.0f} MB) in a Blender process ...", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        self.proc = subprocess.Popen([self.python, str(SERVER)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                     text=True, bufsize=1)
        try:
            inputs = self._send({"op": "open", "file": self.file, "object": self.obj, "modifier": self.modifier})["inputs"]
        except ValueError:
            self._kill()  # a file Blender cannot open (or without the object): no process is left behind
            raise
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

    def generate(self, params: Mapping[str, Any], uv: str | None = None, parts: str | None = None) -> Evaluated:
        """The evaluated mesh for ``params``, with the UV map ``uv`` and the part attribute ``parts``
        where named (:class:`Evaluated`)."""
        out = self.request({"op": "generate", "params": dict(params), "uv": uv, "parts": parts})
        m = int(out["m"])

        def array(key: str, dtype: Any, shape: tuple[int, ...]) -> np.ndarray | None:
            if key not in out:
                return None
            return np.frombuffer(base64.b64decode(out[key]), dtype=dtype).reshape(shape).copy()

        return Evaluated(array("vertices", np.float64, (-1, 3)), array("faces", np.int64, (m, 3)), float(out["seconds"]),
                         [tuple(a) for a in out.get("attributes", [])], array("corner_uv", np.float64, (m, 3, 2)),
                         array("face_parts", np.int64, (m,)), int(out.get("objects", 1)))

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


def input_specs(inputs: list[dict[str, Any]], bounds: Mapping[str, Any] | None = None,
                pins: Mapping[str, Any] | None = None) -> tuple[ParamSpace, dict[str, Any]]:
    """The parameter space of a modifier's inputs (:class:`ParamSpace`) and the pinned values.

    ``bounds`` ``{name: [low, high]}`` narrow float / int ranges (within Blender's); ``pins`` fix
    inputs (they leave the space). An input whose range is unbounded in Blender needs bounds."""
    bounds, pins = dict(bounds or {}), dict(pins or {})
    names = {s["name"] for s in inputs}
    for key in list(bounds) + list(pins):
        if key not in names:
            raise ValueError(f"no input {key!r}; the modifier's inputs are {sorted(names)}")
    specs: list[ParamSpec] = []
    for s in inputs:
        name = s["name"]
        if name in pins:
            continue
        if s["type"] in ("float", "int"):
            lo, hi = _f32(s["min"]), _f32(s["max"])
            if name in bounds:
                b_lo, b_hi = (float(x) for x in bounds[name])
                if not (lo <= b_lo <= b_hi <= hi):
                    raise ValueError(f"bounds for {name!r} must lie within Blender's [{lo:g}, {hi:g}], got [{b_lo:g}, {b_hi:g}]")
                lo, hi = b_lo, b_hi
            if max(abs(lo), abs(hi)) > UNBOUNDED:
                raise ValueError(f"input {name!r} has no usable range in Blender ([{lo:g}, {hi:g}]): give it bounds")
            default = min(max(_f32(s["default"]), lo), hi)
            specs.append(continuous(name, lo, hi, default) if s["type"] == "float" else integer(name, int(lo), int(hi), int(round(default))))
        elif s["type"] == "bool":
            specs.append(choice(name, (False, True), bool(s["default"])))
        elif s["type"] == "menu" and s.get("options"):
            default = s["default"] if s.get("default") in s["options"] else s["options"][0]
            specs.append(choice(name, tuple(s["options"]), default))
    return ParamSpace(tuple(specs)), pins


class BlenderModel(ProceduralModel):
    """A family from a ``.blend`` file's Geometry Nodes modifier (module docstring)."""

    def __init__(self, file: str | os.PathLike, obj: str, modifier: str = "GeometryNodes", bounds: Mapping[str, Any] | None = None,
                 pins: Mapping[str, Any] | None = None, python: str | None = None, uv: str | None = None,
                 parts: str | None = None) -> None:
        super().__init__("adaptive")
        self.session = BlenderSession(file, obj, modifier, python=python)
        self.uv, self.parts = uv, parts
        self.attributes: list[tuple[str, str, str]] = []
        self.name = f"blender:{Path(file).stem}/{obj}"
        self.description = f"Geometry Nodes modifier {modifier!r} of {obj!r} in {Path(file).name}"
        self.space, self.pins = input_specs(self.session.inputs, bounds, pins)
        self.last_seconds = 0.0

    def _build(self, params: Mapping[str, Any]) -> Shape:
        values = {**self.pins, **{k: (v.item() if hasattr(v, "item") else v) for k, v in params.items()}}
        out = self.session.generate(values, uv=self.uv, parts=self.parts)
        self.last_seconds, self.attributes = out.seconds, out.attributes
        if len(out.faces) == 0:
            raise ValueError(f"{self.name}: the evaluated mesh has no faces for {values}")
        vertices, faces = out.vertices, out.faces
        if out.face_parts is not None:  # the graph's parts, not its connectivity
            faces, source = split_by_face_parts(faces, out.face_parts, len(vertices))
            vertices = vertices[source]
        return Shape(vertices, faces, source=self.session.file, corner_uv=out.corner_uv)

    def close(self) -> None:
        self.session.close()


if __name__ == "__main__":  # pragma: no cover
    print(blender_python() or "no Python with bpy", file=sys.stderr)


#: The settings of a ``blender`` source: ``parts`` names an attribute whose values are the parts
#: (instead of the mesh's connectivity); ``uv`` names a UV map the graph makes, kept as the
#: template's UVs (each group's representative keeps its own layout).
BLENDER_KEYS = ("file", "object", "modifier", "pins", "parts", "uv")
