"""The Blender side of a ``.blend`` family source, run by Blender's Python (``bpy``) in its own
process and environment (``.venv-blender``): it imports only the standard library, ``bpy`` and
numpy, never ``proctex``.

Protocol: one JSON request per line on stdin, one JSON answer per line on the protocol stream (the
process's original stdout; Blender's own messages go to stderr). Requests:

- ``{"op": "open", "file": path, "object": name, "modifier": name}`` -> ``{"inputs": [{"name",
  "identifier", "type": "float"|"int"|"bool"|"menu", "default" (the node group's), "value" (what the
  modifier holds in the file), "min", "max", "options"}], "producers": [...], "provenance_error",
  "tree", "object"}``: ``producers`` are the nodes that make geometry in an instrumented copy of the
  tree (:func:`instrument`; ``provenance_error`` says why there is none)
- ``{"op": "generate", "params": {name: value}, "uv": name | null, "parts": name | null}`` ->
  ``{"n": vertices, "m": triangles, "vertices": base64 float64 (n, 3) in object coordinates, "faces": base64 int64 (m, 3),
  "attributes": [[name, domain, type]], "objects": how many objects the depsgraph evaluated, "seconds"}``
  (the evaluated mesh, triangulated, instances realized: a Realize Instances modifier follows the
  model's, in memory; evaluated in a scene of its own holding only the object, so the rest of a
  scene is not evaluated), plus
  ``"corner_uv"`` (base64 float64 (m, 3, 2)) when ``uv`` names a 2D corner attribute (a UV map) and
  ``"face_parts"`` (base64 int64 (m,)) when ``parts`` names a face, point or corner attribute (a
  point or corner attribute gives each triangle its first corner's value). The instrumented tree is
  evaluated unless ``"plain": true``: its answer adds ``"face_source"`` (base64 int64 (m,): the
  producer id per triangle, 0 for none), ``"face_instance"`` (int64 (m,): the realized instance's
  index, -1 for none) and ``"canonical"`` (float64 (n, 3): each vertex in its producer's own
  bounding box, NaN where none stored it). Instrumenting only adds attributes: the vertices and
  faces are those of the plain tree.
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
        if kind != "menu":  # the value the modifier holds in the file: what its panel shows
            try:
                current = modifier[item.identifier]
                spec["value"] = {"float": float, "int": int, "bool": bool}[kind](current)
            except (KeyError, TypeError, ValueError):
                spec["value"] = spec["default"]
        else:
            spec["value"] = spec["default"]
        out.append(spec)
    return out


# ------------------------------------------------------------------------------------ provenance
#: Attribute names the instrumented tree stores (one per domain: a Blender geometry holds one
#: attribute per name, whatever its domain). Producer ids start at 1: 0 (what Join Geometry fills in
#: for geometry without the attribute) means "no producer".
SOURCE = {"POINT": "proctex_src_p", "FACE": "proctex_src_f", "CURVE": "proctex_src_c", "INSTANCE": "proctex_src_i"}
CANONICAL = "proctex_canon"
INSTANCE = "proctex_inst"
#: Nodes that make geometry although they take geometry in (everything with a geometry output and no
#: geometry input makes geometry too: mesh and curve primitives, import nodes, points, text).
MAKERS = {"GeometryNodeCurveToMesh", "GeometryNodeVolumeToMesh", "GeometryNodeFillCurve", "GeometryNodeConvexHull", "GeometryNodeObjectInfo", "GeometryNodeCollectionInfo"}
#: Nodes whose output holds new instances: the instance index is stored after them.
INSTANCERS = {"GeometryNodeInstanceOnPoints", "GeometryNodeGeometryToInstance", "GeometryNodeObjectInfo", "GeometryNodeCollectionInfo"}
MAX_PRODUCERS = 20_000  # a tree with more producing nodes than this is evaluated without provenance
MAX_GROUP_DEPTH = 64


def _is_producer(node, root: bool) -> bool:
    """Whether ``node`` makes geometry (its output is where a face's provenance starts). The root
    tree's Group Input makes the object's own mesh; a nested group's passes geometry through."""
    if node.mute or node.bl_idname in ("NodeFrame", "NodeReroute", "GeometryNodeGroup", "NodeGroupOutput"):
        return False
    if not any(s.type == "GEOMETRY" for s in node.outputs):
        return False
    if node.bl_idname == "NodeGroupInput":
        return root
    return node.bl_idname in MAKERS or not any(s.type == "GEOMETRY" for s in node.inputs)


def _frames(node) -> list[dict]:
    """The frames ``node`` sits in, innermost first: ``{"name", "label"}`` each."""
    out, frame, seen = [], node.parent, set()
    while frame is not None and frame.name not in seen and len(out) < MAX_GROUP_DEPTH:
        seen.add(frame.name)
        out.append({"name": frame.name, "label": frame.label})
        frame = frame.parent
    return out


def _store(ng, geometry, name: str, data_type: str, domain: str, value=None, value_socket=None):
    """A Store Named Attribute node after ``geometry``; its geometry output."""
    node = ng.nodes.new("GeometryNodeStoreNamedAttribute")
    node.data_type, node.domain = data_type, domain
    node.inputs["Name"].default_value = name
    ng.links.new(geometry, node.inputs["Geometry"])
    if value_socket is not None:
        ng.links.new(value_socket, node.inputs["Value"])
    else:
        node.inputs["Value"].default_value = value
    return node.outputs["Geometry"]


def _canonical_field(ng, geometry):
    """(position - box min) / (box max - box min) of ``geometry``: its points in its own box
    (Vector Math's divide gives 0 across a flat axis)."""
    box = ng.nodes.new("GeometryNodeBoundBox")
    ng.links.new(geometry, box.inputs["Geometry"])
    pos = ng.nodes.new("GeometryNodeInputPosition")
    off = ng.nodes.new("ShaderNodeVectorMath")
    off.operation = "SUBTRACT"
    ng.links.new(pos.outputs[0], off.inputs[0])
    ng.links.new(box.outputs["Min"], off.inputs[1])
    size = ng.nodes.new("ShaderNodeVectorMath")
    size.operation = "SUBTRACT"
    ng.links.new(box.outputs["Max"], size.inputs[0])
    ng.links.new(box.outputs["Min"], size.inputs[1])
    div = ng.nodes.new("ShaderNodeVectorMath")
    div.operation = "DIVIDE"
    ng.links.new(off.outputs[0], div.inputs[0])
    ng.links.new(size.outputs[0], div.inputs[1])
    return div.outputs[0]


def _index_plus_one(ng):
    """Index + 1 (0 stays "none": what Join Geometry fills in for geometry that had no instances)."""
    add = ng.nodes.new("ShaderNodeMath")
    add.operation = "ADD"
    ng.links.new(ng.nodes.new("GeometryNodeInputIndex").outputs[0], add.inputs[0])
    add.inputs[1].default_value = 1.0
    return add.outputs[0]


def _reroute(ng, out, new, moved) -> None:
    """The links ``moved`` (that left socket ``out`` before the stores were added) leave socket
    ``new`` instead, as they were: their muting, and their place among the links into a multi-input
    socket (Join Geometry joins in that order, so the order of the vertices depends on it)."""
    ids = {link.as_pointer() for link in moved}
    for target in {link.to_socket.as_pointer(): link.to_socket for link in moved}.values():
        links = sorted(target.links, key=lambda link: link.multi_input_sort_id) if target.is_multi_input else list(target.links)
        kept = [(link.from_socket, link.is_muted, link.as_pointer() in ids) for link in links]
        for link in links:
            ng.links.remove(link)
        for source, muted, move in kept:
            made = ng.links.new(new if move else source, target)
            made.is_muted = muted


def _mark(ng, node, pid: int) -> None:
    """Every linked geometry output of producer ``node`` goes through stores of its id (on every
    domain), its own box coordinates and, for an instancer, the instance index."""
    for out in [s for s in node.outputs if s.type == "GEOMETRY" and s.is_linked]:
        links = list(out.links)
        cur = out
        for domain, name in SOURCE.items():
            cur = _store(ng, cur, name, "INT", domain, value=pid)
        cur = _store(ng, cur, CANONICAL, "FLOAT_VECTOR", "POINT", value_socket=_canonical_field(ng, out))
        if node.bl_idname in INSTANCERS:
            cur = _store(ng, cur, INSTANCE, "INT", "INSTANCE", value_socket=_index_plus_one(ng))
        _reroute(ng, out, cur, links)


def _mark_instances(ng, node) -> None:
    """The instance index stored after an instancing node that makes no geometry of its own."""
    for out in [s for s in node.outputs if s.type == "GEOMETRY" and s.is_linked]:
        links = list(out.links)
        _reroute(ng, out, _store(ng, out, INSTANCE, "INT", "INSTANCE", value_socket=_index_plus_one(ng)), links)


def instrument(bpy, tree, obj) -> tuple[object, list[dict]]:
    """A copy of ``tree`` (and of each nested group, once per use) in which every producing node's
    output carries its producer id, box coordinates and instance index (module docstring), and the
    producers: ``[{"id", "node", "label", "type", "bl_label", "frames", "groups", "data"}]`` (``groups``:
    the group nodes it is nested in, innermost first, as ``{"node", "label", "tree", "frames"}``, the
    frames being those the group node sits in within its parent tree; ``data``: the
    object or collection an Info node reads, the object's own name for the root's Group Input). The
    copies live in memory only (the file is never saved)."""
    producers: list[dict] = []

    def visit(ng, groups: list[dict], depth: int) -> None:
        if depth > MAX_GROUP_DEPTH:
            raise ValueError(f"node groups nested deeper than {MAX_GROUP_DEPTH}")
        nodes = list(ng.nodes)
        for node in nodes:
            if node.bl_idname == "GeometryNodeGroup" and node.node_tree is not None and not node.mute:
                original = node.node_tree.name
                node.node_tree = node.node_tree.copy()
                use = {"node": node.name, "label": node.label, "tree": original, "frames": _frames(node)}
                visit(node.node_tree, [use] + groups, depth + 1)
        for node in nodes:
            if not _is_producer(node, root=depth == 0):
                if node.bl_idname in INSTANCERS and not node.mute:
                    _mark_instances(ng, node)
                continue
            if not any(s.type == "GEOMETRY" and s.is_linked for s in node.outputs):
                continue  # makes nothing anyone uses
            if len(producers) >= MAX_PRODUCERS:
                raise ValueError(f"more than {MAX_PRODUCERS} producing nodes")
            data = None
            if node.bl_idname == "NodeGroupInput":
                data = obj.name
            else:
                for key in ("Object", "Collection"):
                    sock = node.inputs.get(key)
                    if sock is not None and not sock.is_linked and getattr(sock, "default_value", None) is not None:
                        data = sock.default_value.name
            pid = len(producers) + 1
            producers.append({"id": pid, "node": node.name, "label": node.label, "type": node.bl_idname, "bl_label": node.bl_label, "frames": _frames(node), "groups": groups, "data": data})
            _mark(ng, node, pid)

    copy = tree.copy()
    visit(copy, [], 0)
    return copy, producers


def _provenance(mesh, tris, polygon, n: int):
    """Per triangle: the producer id (0: none) and instance index (-1: none); per vertex: the box
    coordinates (NaN where no producer stored them)."""
    import numpy as np

    m = len(polygon)
    source = np.zeros(m, dtype=np.int64)
    face = mesh.attributes.get(SOURCE["FACE"])
    if face is not None and face.domain == "FACE":
        values = np.empty(len(face.data), dtype=np.int32)
        face.data.foreach_get("value", values)
        source = values[polygon].astype(np.int64)
    point = mesh.attributes.get(SOURCE["POINT"])
    if point is not None and point.domain == "POINT" and (source == 0).any():
        values = np.empty(len(point.data), dtype=np.int32)
        point.data.foreach_get("value", values)
        first = values[tris[0::3]]
        source = np.where(source == 0, first, source)
    instance = np.full(m, -1, dtype=np.int64)
    inst = mesh.attributes.get(INSTANCE)
    if inst is not None and inst.domain in ("POINT", "FACE"):
        values = np.empty(len(inst.data), dtype=np.int32)
        inst.data.foreach_get("value", values)
        instance = (values[polygon] if inst.domain == "FACE" else values[tris[0::3]]).astype(np.int64) - 1
    canonical = np.full((n, 3), np.nan)
    canon = mesh.attributes.get(CANONICAL)
    if canon is not None and canon.domain == "POINT" and canon.data_type == "FLOAT_VECTOR":
        values = np.empty(len(canon.data) * 3, dtype=np.float32)
        canon.data.foreach_get("vector", values)
        canonical = values.reshape(-1, 3).astype(np.float64)
    return source, instance, canonical


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
                inputs = _inputs(mod)
                plain, instrumented, producers, why = mod.node_group, None, [], None
                try:
                    instrumented, producers = instrument(bpy, plain, obj)
                except Exception as exc:  # a tree it cannot instrument is evaluated as it is
                    why = f"{type(exc).__name__}: {exc}"[:500]
                _realize_after(bpy, obj, mod)
                solo = _solo_scene(bpy, obj)
                state.update(obj=obj, mod=mod, inputs=inputs, solo=solo, plain=plain, instrumented=instrumented)
                answer({"inputs": inputs, "producers": producers, "provenance_error": why, "tree": plain.name, "object": obj.name})
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
                tree = state["plain"] if req.get("plain") or state["instrumented"] is None else state["instrumented"]
                if state["mod"].node_group != tree:  # the same interface: the inputs' values stay
                    state["mod"].node_group = tree
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
                    extra = {"attributes": [[a.name, a.domain, a.data_type] for a in mesh.attributes if not a.name.startswith((".", "proctex_"))], "objects": n_objects}
                    if req.get("uv") or req.get("parts"):
                        loops = np.empty(m * 3, dtype=np.int32)
                        mesh.loop_triangles.foreach_get("loops", loops)
                    if tree is state["instrumented"]:
                        polygon = np.empty(m, dtype=np.int32)
                        mesh.loop_triangles.foreach_get("polygon_index", polygon)
                        source, instance, canonical = _provenance(mesh, tris, polygon, n)
                        extra["face_source"] = base64.b64encode(source.tobytes()).decode()
                        extra["face_instance"] = base64.b64encode(instance.tobytes()).decode()
                        extra["canonical"] = base64.b64encode(canonical.tobytes()).decode()
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
                answer(
                    {
                        "n": n,
                        "m": m,
                        "vertices": base64.b64encode(np.ascontiguousarray(v).tobytes()).decode(),
                        "faces": base64.b64encode(tris.astype(np.int64).tobytes()).decode(),
                        "seconds": time.perf_counter() - t0,
                        **extra,
                    }
                )
            else:
                raise ValueError(f"unknown op {op!r}")
        except Exception as exc:  # one bad request: say why, keep serving
            answer({"error": f"{type(exc).__name__}: {exc}"[:2000]})
    return 0


if __name__ == "__main__":
    sys.exit(main())
