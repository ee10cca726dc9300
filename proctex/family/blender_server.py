"""The Blender side of a ``.blend`` family source, run by Blender's Python (``bpy``) in its own
process and environment (``.venv-blender``): it imports only the standard library, ``bpy`` and
numpy, never ``proctex``.

Protocol: one JSON request per line on stdin, one JSON answer per line on the protocol stream (the
process's original stdout; Blender's own messages go to stderr). Requests:

- ``{"op": "open", "file": path, "object": name, "modifier": name}`` -> ``{"inputs": [{"name",
  "identifier", "type": "float"|"int"|"bool"|"menu", "default", "min", "max", "options"}]}``
- ``{"op": "generate", "params": {name: value}}`` -> ``{"n": vertices, "m": triangles, "vertices":
  base64 float64 (n, 3), "faces": base64 int64 (m, 3), "seconds"}`` (the evaluated mesh, triangulated)
- ``{"op": "quit"}``

Errors answer ``{"error": message}``; the process keeps serving.
"""

from __future__ import annotations

import base64
import json
import os
import sys
import time


def _inputs(modifier) -> list[dict]:
    out = []
    for item in modifier.node_group.interface.items_tree:
        if getattr(item, "item_type", "") != "SOCKET" or item.in_out != "INPUT":
            continue
        kind = {"NodeSocketFloat": "float", "NodeSocketInt": "int", "NodeSocketBool": "bool", "NodeSocketMenu": "menu"}.get(item.socket_type)
        if kind is None:
            continue  # geometry, objects, materials...: not parameters of the family
        spec = {"name": item.name, "identifier": item.identifier, "type": kind, "default": getattr(item, "default_value", None)}
        if kind in ("float", "int"):
            spec.update(min=item.min_value, max=item.max_value)
        if kind == "menu":
            current = modifier[item.identifier]
            spec["options"] = [current] if isinstance(current, str) else []
        if kind == "bool":
            spec["default"] = bool(spec["default"])
        out.append(spec)
    return out


def main() -> int:
    proto = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)  # Blender prints to stdout: keep it off the protocol stream
    import bpy
    import numpy as np

    state: dict = {}

    def answer(data: dict) -> None:
        proto.write(json.dumps(data) + "\n")

    for line in sys.stdin:
        if not line.strip():
            continue
        try:
            req = json.loads(line)
            op = req.get("op")
            if op == "quit":
                answer({"ok": True})
                return 0
            if op == "open":
                bpy.ops.wm.open_mainfile(filepath=str(req["file"]))
                obj = bpy.data.objects.get(req["object"])
                if obj is None:
                    raise ValueError(f"no object {req['object']!r} in {req['file']}; objects: {sorted(o.name for o in bpy.data.objects)[:20]}")
                mod = obj.modifiers.get(req["modifier"])
                if mod is None or mod.type != "NODES" or mod.node_group is None:
                    names = [m.name for m in obj.modifiers if m.type == "NODES"]
                    raise ValueError(f"object {req['object']!r} has no Geometry Nodes modifier {req['modifier']!r}; it has {names}")
                state.update(obj=obj, mod=mod, inputs=_inputs(mod))
                answer({"inputs": state["inputs"]})
            elif op == "generate":
                if "obj" not in state:
                    raise ValueError("open a file first")
                t0 = time.perf_counter()
                ids = {s["name"]: s for s in state["inputs"]}
                for name, value in (req.get("params") or {}).items():
                    if name not in ids:
                        raise ValueError(f"unknown input {name!r}; inputs: {sorted(ids)}")
                    kind = ids[name]["type"]
                    state["mod"][ids[name]["identifier"]] = {"float": float, "int": int, "bool": bool}.get(kind, str)(value)
                obj = state["obj"]
                obj.update_tag()  # without it the depsgraph keeps the previous evaluation
                depsgraph = bpy.context.evaluated_depsgraph_get()
                depsgraph.update()
                evaluated = obj.evaluated_get(depsgraph)
                mesh = evaluated.to_mesh()
                try:
                    mesh.calc_loop_triangles()
                    n, m = len(mesh.vertices), len(mesh.loop_triangles)
                    verts = np.empty(n * 3, dtype=np.float64)
                    mesh.vertices.foreach_get("co", verts)
                    tris = np.empty(m * 3, dtype=np.int32)
                    mesh.loop_triangles.foreach_get("vertices", tris)
                finally:
                    evaluated.to_mesh_clear()
                world = np.array(obj.matrix_world, dtype=np.float64)
                v = verts.reshape(-1, 3) @ world[:3, :3].T + world[:3, 3]
                answer({"n": n, "m": m, "vertices": base64.b64encode(np.ascontiguousarray(v).tobytes()).decode(),
                        "faces": base64.b64encode(tris.astype(np.int64).tobytes()).decode(), "seconds": time.perf_counter() - t0})
            else:
                raise ValueError(f"unknown op {op!r}")
        except Exception as exc:  # one bad request: say why, keep serving
            answer({"error": f"{type(exc).__name__}: {exc}"[:2000]})
    return 0


if __name__ == "__main__":
    sys.exit(main())
