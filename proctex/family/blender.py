"""A Blender Geometry Nodes model as a family source: the ``.blend`` file is a black box whose
modifier inputs are the family's parameters (issue 19, first slice).

Blender's Python (``bpy`` from PyPI) needs numpy < 2, so it runs in its own environment
(``.venv-blender``, made by ``make blender``) and its own long-lived process, which opens the file
once (:mod:`proctex.family.blender_server`, spoken to over a pipe, one JSON line per request).
:class:`BlenderModel` is a :class:`~proctex.geometry.shape.ProceduralModel`: its parameter space is
read from the modifier's exposed inputs (float / int / bool / menu, with the node group's
min / max / default), which ``bounds`` may narrow and ``pins`` may fix; ``generate(params)`` sets
the inputs, evaluates the depsgraph headless and returns the evaluated, triangulated mesh in world
coordinates.
"""

from __future__ import annotations

import base64
import json
import os
import select
import subprocess
import sys
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from proctex.geometry.shape import ProceduralModel, Shape
from proctex.params import ParamSpace, ParamSpec, choice, continuous, integer

SERVER = Path(__file__).with_name("blender_server.py")
REPO = Path(__file__).resolve().parents[2]
UNBOUNDED = 1e6  # a Blender input range wider than this is "no range given": the config must narrow it


def blender_python() -> str | None:
    """The Python that has ``bpy``: ``$PROCTEX_BLENDER_PYTHON``, else ``.venv-blender/bin/python`` in
    the repository; None when neither exists."""
    env = os.environ.get("PROCTEX_BLENDER_PYTHON")
    if env:
        return env
    local = REPO / ".venv-blender" / "bin" / "python"
    return str(local) if local.exists() else None


class BlenderSession:
    """One Blender process with one ``.blend`` file open (:mod:`proctex.family.blender_server`)."""

    def __init__(self, file: str | os.PathLike, obj: str, modifier: str = "GeometryNodes", python: str | None = None,
                 timeout: float = 120.0) -> None:
        self.file = str(Path(file).resolve())
        if not Path(self.file).is_file():
            raise ValueError(f"{file}: no such .blend file")
        self.python = python or blender_python()
        if not self.python:
            raise ValueError("no Python with bpy: run `make blender` (it makes .venv-blender) or set PROCTEX_BLENDER_PYTHON")
        self.timeout = timeout
        self.proc = subprocess.Popen([self.python, str(SERVER)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                     text=True, bufsize=1)
        self.inputs: list[dict[str, Any]] = self.request({"op": "open", "file": self.file, "object": obj, "modifier": modifier})["inputs"]

    def request(self, req: dict[str, Any]) -> dict[str, Any]:
        """Send one request; its answer, or ``ValueError`` with Blender's error, or when the process
        died or did not answer within ``timeout`` seconds."""
        if self.proc.poll() is not None:
            raise ValueError(f"the Blender process for {self.file} has exited ({self.proc.returncode})")
        self.proc.stdin.write(json.dumps(req) + "\n")
        self.proc.stdin.flush()
        ready, _, _ = select.select([self.proc.stdout], [], [], self.timeout)
        if not ready:
            self.close()
            raise ValueError(f"Blender did not answer {req.get('op')!r} within {self.timeout:g} s ({self.file})")
        line = self.proc.stdout.readline()
        if not line:
            raise ValueError(f"the Blender process for {self.file} ended without an answer")
        data = json.loads(line)
        if "error" in data:
            raise ValueError(f"{self.file}: {data['error']}")
        return data

    def generate(self, params: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray, float]:
        """``(vertices (n, 3) float64, faces (m, 3) int64, seconds Blender took)`` of the evaluated mesh."""
        out = self.request({"op": "generate", "params": dict(params)})
        v = np.frombuffer(base64.b64decode(out["vertices"]), dtype=np.float64).reshape(-1, 3)
        f = np.frombuffer(base64.b64decode(out["faces"]), dtype=np.int64).reshape(-1, 3)
        return v.copy(), f.copy(), float(out["seconds"])

    def close(self) -> None:
        if self.proc.poll() is None:
            try:
                self.proc.stdin.write(json.dumps({"op": "quit"}) + "\n")
                self.proc.stdin.flush()
                self.proc.wait(timeout=10)
            except (OSError, subprocess.TimeoutExpired, ValueError):
                self.proc.kill()
                self.proc.wait()

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
            specs.append(choice(name, tuple(s["options"]), s["options"][0]))
    return ParamSpace(tuple(specs)), pins


class BlenderModel(ProceduralModel):
    """A family from a ``.blend`` file's Geometry Nodes modifier (module docstring)."""

    def __init__(self, file: str | os.PathLike, obj: str, modifier: str = "GeometryNodes", bounds: Mapping[str, Any] | None = None,
                 pins: Mapping[str, Any] | None = None, python: str | None = None) -> None:
        super().__init__("adaptive")
        self.session = BlenderSession(file, obj, modifier, python=python)
        self.name = f"blender:{Path(file).stem}/{obj}"
        self.description = f"Geometry Nodes modifier {modifier!r} of {obj!r} in {Path(file).name}"
        self.space, self.pins = input_specs(self.session.inputs, bounds, pins)
        self.last_seconds = 0.0

    def _build(self, params: Mapping[str, Any]) -> Shape:
        values = {**self.pins, **{k: (v.item() if hasattr(v, "item") else v) for k, v in params.items()}}
        vertices, faces, self.last_seconds = self.session.generate(values)
        if len(faces) == 0:
            raise ValueError(f"{self.name}: the evaluated mesh has no faces for {values}")
        return Shape(vertices, faces, source=self.session.file)

    def close(self) -> None:
        self.session.close()


if __name__ == "__main__":  # pragma: no cover
    print(blender_python() or "no Python with bpy", file=sys.stderr)
