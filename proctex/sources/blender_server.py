"""The Blender side of a ``.blend`` family source, run by Blender's Python (``bpy``) in its own
process and environment (``.venv-blender``): it imports only the standard library, ``bpy`` and
numpy, never ``proctex``.

Protocol: one JSON request per line on stdin, one JSON answer per line on the protocol stream (the
process's original stdout; Blender's own messages go to stderr). Requests:

- ``{"op": "open", "file": path, "object": name, "modifier": name}`` -> ``{"inputs": [{"name",
  "identifier", "type": "float"|"int"|"bool"|"menu", "default", "min", "max", "options"}]}``
- ``{"op": "generate", "params": {name: value}, "uv": name | null, "parts": name | null}`` ->
  ``{"n": vertices, "m": triangles, "vertices": base64 float64 (n, 3) in object coordinates, "faces": base64 int64 (m, 3),
  "attributes": [[name, domain, type]], "objects": how many objects the depsgraph evaluated, "seconds"}``
  (the evaluated mesh, triangulated, instances realized: a Realize Instances modifier follows the
  model's, in memory; evaluated in a scene of its own holding only the object, so the rest of a
  scene is not evaluated), plus
  ``"corner_uv"`` (base64 float64 (m, 3, 2)) when ``uv`` names a 2D corner attribute (a UV map) and
  ``"face_parts"`` (base64 int64 (m,)) when ``parts`` names a face, point or corner attribute (a
  point or corner attribute gives each triangle its first corner's value).
- ``{"op": "quit"}``

Errors answer ``{"error": message}``; the process keeps serving.
"""

from __future__ import annotations

import base64
import json
import os
import sys
import time

SCALAR = {"FLOAT", "INT", "BOOLEAN", "INT8"}
ROW = {"FLOAT2": 2, "FLOAT_VECTOR": 3}


def _attribute(mesh, name: str, want: str):
    """One attribute of ``mesh`` as a numpy array: ``want="uv"`` a 2D corner attribute ((corners, 2)),
    ``want="parts"`` a scalar one ((elements,), with its domain)."""
    import numpy as np

    attr = mesh.attributes.get(name)
    if attr is None:
        names = sorted(a.name for a in mesh.attributes if not a.name.startswith("."))
        raise ValueError(f"the evaluated mesh has no attribute {name!r}; it has {names}")
    if want == "uv":
        if attr.domain != "CORNER" or attr.data_type != "FLOAT2":
            raise ValueError(f"attribute {name!r} is {attr.data_type} on {attr.domain}, not a UV map (2D vector on face corners)")
        out = np.empty(len(attr.data) * 2, dtype=np.float32)
        attr.data.foreach_get("vector", out)
        return out.reshape(-1, 2), attr.domain
    if attr.data_type not in SCALAR or attr.domain not in ("FACE", "POINT", "CORNER"):
        raise ValueError(f"attribute {name!r} is {attr.data_type} on {attr.domain}: parts need an integer, float or boolean value per face, point or corner")
    dtype = np.float32 if attr.data_type == "FLOAT" else (bool if attr.data_type == "BOOLEAN" else np.int32)
    out = np.empty(len(attr.data), dtype=dtype)
    attr.data.foreach_get("value", out)
    return out, attr.domain


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
        if kind == "menu":  # the modifier keeps a menu as an int whose items name the options
            items = modifier.id_properties_ui(item.identifier).as_dict().get("items") or []
            spec["options"] = [it[0] for it in items]
            spec["values"] = [it[4] for it in items]
            current = modifier[item.identifier]
            spec["default"] = next((it[0] for it in items if it[4] == current), spec["options"][0] if items else None)
        if kind == "bool":
            spec["default"] = bool(spec["default"])
        out.append(spec)
    return out


REALIZE = "ProcTexRealize"
SOLO = "ProcTexSolo"


def _realize_after(bpy, obj, mod) -> None:
    """Instances realized right after the model's modifier (a Realize Instances node group in a
    modifier of its own, in memory only): ``to_mesh`` drops instances otherwise (legs, leaves,
    bricks made with Instance on Points). Realizing meshes that are already real changes nothing."""
    ng = bpy.data.node_groups.get(REALIZE)
    if ng is None:
        ng = bpy.data.node_groups.new(REALIZE, "GeometryNodeTree")
        ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
        ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
        gin, gout = ng.nodes.new("NodeGroupInput"), ng.nodes.new("NodeGroupOutput")
        real = ng.nodes.new("GeometryNodeRealizeInstances")
        ng.links.new(gin.outputs[0], real.inputs[0])
        ng.links.new(real.outputs[0], gout.inputs[0])
    extra = obj.modifiers.get(REALIZE) or obj.modifiers.new(REALIZE, "NODES")
    extra.node_group = ng
    obj.modifiers.move(list(obj.modifiers).index(extra), list(obj.modifiers).index(mod) + 1)


def _solo_scene(bpy, obj):
    """A scene holding only the model's object: its depsgraph evaluates that object and what it
    depends on (objects its graph reads), not every visible object of a file that holds a scene."""
    solo = bpy.data.scenes.get(SOLO) or bpy.data.scenes.new(SOLO)
    if obj.name not in solo.collection.objects:
        solo.collection.objects.link(obj)
    return solo


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
                _realize_after(bpy, obj, mod)
                solo = _solo_scene(bpy, obj)
                state.update(obj=obj, mod=mod, inputs=_inputs(mod), solo=solo)
                answer({"inputs": state["inputs"]})
            elif op == "generate":
                if "obj" not in state:
                    raise ValueError("open a file first")
                t0 = time.perf_counter()
                ids = {s["name"]: s for s in state["inputs"]}
                for name, value in (req.get("params") or {}).items():
                    if name not in ids:
                        raise ValueError(f"unknown input {name!r}; inputs: {sorted(ids)}")
                    spec = ids[name]
                    if spec["type"] == "menu":
                        if value not in spec["options"]:
                            raise ValueError(f"{name!r} must be one of {spec['options']}, got {value!r}")
                        value = spec["values"][spec["options"].index(value)]
                    else:
                        value = {"float": float, "int": int, "bool": bool}[spec["type"]](value)
                    state["mod"][spec["identifier"]] = value
                obj = state["obj"]
                obj.update_tag()  # without it the depsgraph keeps the previous evaluation
                solo = state["solo"]
                with bpy.context.temp_override(scene=solo, view_layer=solo.view_layers[0]):
                    depsgraph = bpy.context.evaluated_depsgraph_get()
                    depsgraph.update()
                    evaluated = obj.evaluated_get(depsgraph)
                    n_objects = sum(1 for _ in depsgraph.objects)
                mesh = evaluated.to_mesh()
                try:
                    mesh.calc_loop_triangles()
                    n, m = len(mesh.vertices), len(mesh.loop_triangles)
                    verts = np.empty(n * 3, dtype=np.float64)
                    mesh.vertices.foreach_get("co", verts)
                    tris = np.empty(m * 3, dtype=np.int32)
                    mesh.loop_triangles.foreach_get("vertices", tris)
                    extra = {"attributes": [[a.name, a.domain, a.data_type] for a in mesh.attributes if not a.name.startswith(".")],
                             "objects": n_objects}
                    if req.get("uv") or req.get("parts"):
                        loops = np.empty(m * 3, dtype=np.int32)
                        mesh.loop_triangles.foreach_get("loops", loops)
                    if req.get("uv"):
                        uv, _ = _attribute(mesh, str(req["uv"]), "uv")
                        extra["corner_uv"] = base64.b64encode(uv[loops].astype(np.float64).tobytes()).decode()
                    if req.get("parts"):
                        values, domain = _attribute(mesh, str(req["parts"]), "parts")
                        if domain == "FACE":
                            polygon = np.empty(m, dtype=np.int32)
                            mesh.loop_triangles.foreach_get("polygon_index", polygon)
                            per_tri = values[polygon]
                        else:
                            per_tri = values[(tris if domain == "POINT" else loops)[0::3]]
                        if not np.all(np.isfinite(per_tri)):
                            raise ValueError(f"attribute {req['parts']!r} has non-finite values")
                        _, ids = np.unique(per_tri, return_inverse=True)
                        extra["face_parts"] = base64.b64encode(ids.astype(np.int64).tobytes()).decode()
                finally:
                    evaluated.to_mesh_clear()
                v = verts.reshape(-1, 3)  # object coordinates: the object's placement in the file is not the shape
                answer({"n": n, "m": m, "vertices": base64.b64encode(np.ascontiguousarray(v).tobytes()).decode(),
                        "faces": base64.b64encode(tris.astype(np.int64).tobytes()).decode(), "seconds": time.perf_counter() - t0, **extra})
            else:
                raise ValueError(f"unknown op {op!r}")
        except Exception as exc:  # one bad request: say why, keep serving
            answer({"error": f"{type(exc).__name__}: {exc}"[:2000]})
    return 0


if __name__ == "__main__":
    sys.exit(main())
