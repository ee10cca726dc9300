"""ProcTex inside Blender: texture the selected object (or a new variant of a family) through a
running ProcTex service.

The sidebar panel (3D view, N, "ProcTex") holds the service URL, a family picker filled from
``/v1/families``, a look picker filled from the family's ``/looks`` and the family's parameters as
properties. "Texture selected" sends the selected
object's evaluated mesh (object coordinates, modifiers applied) to the family's transfer route and
imports the returned GLB in its place: same transform, the original hidden, a second texturing
replacing the first copy. "Add variant" asks for the family's own shape at the panel's parameters.

Network calls run in worker threads; everything that touches Blender's data runs on the main thread,
from a queue drained by a ``bpy.app.timers`` function (:func:`drain`).
"""

import json
import os
import queue
import tempfile
import threading
from typing import Any, Callable

import bpy
from bpy.props import BoolProperty, CollectionProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty, StringProperty

from . import client

bl_info = {
    "name": "ProcTex",
    "author": "ProcTex",
    "version": (0, 1, 0),
    "blender": (4, 2, 0),
    "location": "View3D > Sidebar > ProcTex",
    "description": "Texture procedural shapes through a ProcTex service",
    "category": "Material",
}

_results: queue.Queue = queue.Queue()
_state: dict[str, Any] = {"pending": 0, "families": [], "looks": []}
_ENUM_CACHE: dict[str, list] = {}  # Blender needs the items of a dynamic enum kept alive


# --------------------------------------------------------------------------------------- the work
def _start(kind: str, call: Callable[[], Any], **meta: Any) -> None:
    """Run ``call`` in a worker thread; its result (or error) comes back through the queue."""

    def work() -> None:
        try:
            _results.put((kind, call(), meta))
        except client.ServiceError as exc:
            _results.put(("error", str(exc), meta))
        except Exception as exc:  # noqa: BLE001 - a worker must always report back
            _results.put(("error", f"{type(exc).__name__}: {exc}", meta))

    _state["pending"] += 1
    threading.Thread(target=work, name=f"proctex-{kind}", daemon=True).start()
    if not bpy.app.timers.is_registered(drain):
        bpy.app.timers.register(drain, first_interval=0.1)


def busy() -> bool:
    """Whether requests are still under way or their results not yet applied."""
    return _state["pending"] > 0 or not _results.empty()


def drain() -> float | None:
    """Apply every finished request to the scene (main thread: the timer). Returns the interval to
    run again, or None when nothing is pending."""
    while True:
        try:
            kind, value, meta = _results.get_nowait()
        except queue.Empty:
            break
        _state["pending"] = max(0, _state["pending"] - 1)
        settings = _settings(meta.get("scene"))
        try:
            if kind == "error":
                settings.status = f"error: {value}"
                print(f"ProcTex: {value}")
            elif kind == "families":
                _state["families"] = value
                settings.status = f"{len(value)} families"
            elif kind == "looks":
                _state["looks"] = value
                if value:
                    settings.look = value[0]["name"]  # the build's look
            elif kind == "describe":
                _fill_params(settings, value)
                _state["parts_attribute"] = value.get("parts_attribute")
                settings.status = f"{meta['family']}: {len(value.get('parameters', []))} parameters, {len(value.get('groups', []))} groups"
            elif kind == "photo_look":
                settings.status = f"look {value.get('name', '?')} painted from the photo in {value.get('seconds', 0):.1f} s"
                url, family = meta["url"], meta["family"]
                _start("looks", lambda: client.looks(url, family), family=family, scene=meta.get("scene"))
            elif kind == "glb":
                data, summary = value
                obj = _import_glb(data, meta)
                settings.status = f"{obj.name}: textured in {summary['seconds']:.2f} s" + (f" ({'; '.join(summary['notes'])[:200]})" if summary["notes"] else "")
        except Exception as exc:  # noqa: BLE001 - a bad answer must not break the timer
            settings.status = f"error: {type(exc).__name__}: {exc}"
            print(f"ProcTex: {settings.status}")
    return 0.1 if busy() else None


def _settings(scene_name: str | None):
    scene = bpy.data.scenes.get(scene_name) if scene_name else None
    return (scene or bpy.context.scene).proctex


# ---------------------------------------------------------------------------------- mesh in, GLB out
def _triangle_parts(mesh, name: str | None) -> list | None:
    """Per loop triangle the value of the part attribute ``name`` (face, point or corner domain;
    a point or corner attribute gives a triangle its first corner's value), or None without it."""
    attr = mesh.attributes.get(name) if name else None
    if attr is None or attr.domain not in ("FACE", "POINT", "CORNER") or attr.data_type not in ("INT", "FLOAT", "BOOLEAN", "INT8"):
        return None
    values = [0] * len(attr.data)
    attr.data.foreach_get("value", values)
    m = len(mesh.loop_triangles)
    if attr.domain == "FACE":
        index = [0] * m
        mesh.loop_triangles.foreach_get("polygon_index", index)
    else:
        corners = [0] * (3 * m)
        mesh.loop_triangles.foreach_get("vertices" if attr.domain == "POINT" else "loops", corners)
        index = corners[0::3]
    return [values[i] for i in index]


def evaluated_obj_text(obj, depsgraph, parts_attribute: str | None = None) -> bytes:
    """OBJ text of ``obj``'s evaluated mesh (modifiers applied), triangulated, in object coordinates;
    with the family's part attribute (``parts_attribute``) on the mesh, one OBJ group per part, so
    the service keeps touching parts apart as the family's own shapes do."""
    evaluated = obj.evaluated_get(depsgraph)
    mesh = evaluated.to_mesh()
    try:
        mesh.calc_loop_triangles()
        verts = [0.0] * (3 * len(mesh.vertices))
        mesh.vertices.foreach_get("co", verts)
        tris = [0] * (3 * len(mesh.loop_triangles))
        mesh.loop_triangles.foreach_get("vertices", tris)
        parts = _triangle_parts(mesh, parts_attribute)
    finally:
        evaluated.to_mesh_clear()
    if not tris:
        raise ValueError(f"{obj.name} has no faces to texture")
    return client.obj_text(verts, tris, parts)


def _import_glb(data: bytes, meta: dict[str, Any]):
    """Import a GLB; place it on the source object (same transform, the source hidden, an earlier
    copy replaced) or at the 3D cursor. Returns the new mesh object."""
    source = bpy.data.objects.get(meta["source"]) if meta.get("source") else None
    if source is not None:
        for old in [o for o in bpy.data.objects if o.get("proctex_source") == source.name]:
            bpy.data.objects.remove(old, do_unlink=True)
    before = set(bpy.data.objects)
    fd, path = tempfile.mkstemp(suffix=".glb", prefix="proctex-")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        result = bpy.ops.import_scene.gltf(filepath=path)
    finally:
        os.remove(path)
    if "FINISHED" not in result:
        raise ValueError(f"Blender could not import the answer ({result})")
    new = [o for o in bpy.data.objects if o not in before]
    meshes = [o for o in new if o.type == "MESH"]
    if not meshes:
        raise ValueError("the answer held no mesh")
    place = source.matrix_world.copy() if source is not None else bpy.context.scene.cursor.matrix.copy()
    for o in new:
        if o.parent is None and o.type == "MESH" and not o.children:
            o.data.transform(o.matrix_world)  # the importer's axis turn goes into the mesh: the copy gets exactly the source's transform
            o.matrix_world = place
        elif o.parent is None:
            o.matrix_world = place @ o.matrix_world
    obj = meshes[0]
    obj.name = f"{source.name}.proctex" if source is not None else f"{meta['family']}.variant"
    obj["proctex_family"] = meta["family"]
    if source is not None:
        obj["proctex_source"] = source.name
        source.hide_set(True)
        source.hide_render = True
    return obj


# ------------------------------------------------------------------------------------ properties
def _family_items(self, context):
    items = [(f["name"], f["name"], f"health: {f['health']}") for f in _state["families"]]
    _ENUM_CACHE["families"] = items or [("", "(refresh the list)", "no families yet")]
    return _ENUM_CACHE["families"]


def _family_changed(self, context) -> None:
    if self.family:
        url, name = self.url, self.family
        _state["looks"] = []
        _start("describe", lambda: client.describe(url, name), family=name, scene=context.scene.name)
        _start("looks", lambda: client.looks(url, name), family=name, scene=context.scene.name)


def _look_items(self, context):
    items = [(lk["name"], lk["name"], str(lk.get("prompt", ""))[:200]) for lk in _state["looks"]]
    _ENUM_CACHE["looks"] = items or [("", "(the build's look)", "pick a family first")]
    return _ENUM_CACHE["looks"]


def _choice_items(self, context):
    options = json.loads(self.options or "[]")
    items = [(json.dumps(o), str(o), "") for o in options]
    _ENUM_CACHE[f"choice:{self.name}"] = items or [("null", "-", "")]
    return _ENUM_CACHE[f"choice:{self.name}"]


def _clamp(self, context) -> None:
    if self.kind == "continuous" and not (self.low <= self.value_float <= self.high):
        self.value_float = min(max(self.value_float, self.low), self.high)
    if self.kind == "integer" and not (self.low <= self.value_int <= self.high):
        self.value_int = int(min(max(self.value_int, self.low), self.high))


class ProcTexParam(bpy.types.PropertyGroup):
    """One family parameter: its spec and its value in the slot of its kind."""

    kind: StringProperty()
    low: FloatProperty()
    high: FloatProperty()
    options: StringProperty(description="JSON list of a choice's options")
    value_float: FloatProperty(update=_clamp)
    value_int: IntProperty(update=_clamp)
    value_choice: EnumProperty(items=_choice_items)

    def value(self) -> Any:
        if self.kind == "continuous":
            return float(self.value_float)
        if self.kind == "integer":
            return int(self.value_int)
        return json.loads(self.value_choice)


class ProcTexSettings(bpy.types.PropertyGroup):
    url: StringProperty(name="Service", default=client.DEFAULT_URL, description="The ProcTex service's URL")
    family: EnumProperty(name="Family", items=_family_items, update=_family_changed)
    look: EnumProperty(name="Look", items=_look_items, description="the family's look (painted with its own prompt) to texture with")
    params: CollectionProperty(type=ProcTexParam)
    accepts_params: BoolProperty(default=False)
    seed: IntProperty(name="Seed", default=0, min=0)
    status: StringProperty(name="Status", default="")
    token: StringProperty(name="Edit token", subtype="PASSWORD", description="the service's edit token (new looks need it)")
    photo_look: StringProperty(name="New look", default="photo", description="the name of the look the photo paints")
    photo_part: StringProperty(name="Part", default="*", description="the part the photo goes on: a group number, part name or part word, or * for every part")
    photo_scale: StringProperty(name="Photo width", default="", description="how much surface the photo's width spans (0.5, 50cm); empty: half the part's longest side")


def _fill_params(settings, description: dict[str, Any]) -> None:
    settings.params.clear()
    settings.accepts_params = "params" in description.get("inputs", [])
    for spec in description.get("parameters", []):
        p = settings.params.add()
        p.name, p.kind = str(spec["name"]), str(spec.get("kind", "continuous"))
        if p.kind in ("continuous", "integer"):
            p.low, p.high = float(spec["low"]), float(spec["high"])
            if p.kind == "continuous":
                p.value_float = float(spec.get("default", p.low))
            else:
                p.value_int = int(spec.get("default", p.low))
        else:
            p.options = json.dumps(list(spec.get("options", [])))
            p.value_choice = json.dumps(spec.get("default"))


# ------------------------------------------------------------------------------------- operators
class PROCTEX_OT_refresh(bpy.types.Operator):
    """List the service's families"""

    bl_idname = "proctex.refresh"
    bl_label = "Refresh families"

    def execute(self, context):
        url = context.scene.proctex.url
        _start("families", lambda: client.families(url), scene=context.scene.name)
        return {"FINISHED"}


class PROCTEX_OT_texture_selected(bpy.types.Operator):
    """Texture the active object's evaluated mesh with the family and show the result in its place"""

    bl_idname = "proctex.texture_selected"
    bl_label = "Texture selected"

    @classmethod
    def poll(cls, context):
        obj = context.active_object
        return obj is not None and obj.type in {"MESH", "CURVE", "SURFACE", "META", "FONT"}

    def execute(self, context):
        settings = context.scene.proctex
        if not settings.family:
            self.report({"ERROR"}, "pick a family first (Refresh families)")
            return {"CANCELLED"}
        obj = context.active_object
        try:
            text = evaluated_obj_text(obj, context.evaluated_depsgraph_get(), _state.get("parts_attribute"))
        except ValueError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        url, name, seed, look = settings.url, settings.family, settings.seed, settings.look or None
        settings.status = f"texturing {obj.name}..."
        _start("glb", lambda: client.transfer_mesh(url, name, text, seed, look=look), source=obj.name, family=name, scene=context.scene.name)
        return {"FINISHED"}


def active_image(obj) -> tuple[str, bytes]:
    """``(file name, bytes)`` of the image texture on ``obj``'s active material (the active node when it
    is an Image Texture, else the first one with an image): its packed data, its file, or (a generated
    or edited image) a PNG written from its pixels. ``ValueError`` when it has none."""
    mat = obj.active_material if obj is not None else None
    tree = mat.node_tree if mat is not None and mat.use_nodes else None
    if tree is None:
        raise ValueError("the active object has no material with nodes: give it an Image Texture")
    nodes = [n for n in ([tree.nodes.active] if tree.nodes.active is not None else []) + list(tree.nodes) if n.type == "TEX_IMAGE" and n.image is not None]
    if not nodes:
        raise ValueError(f"material {mat.name!r} has no Image Texture node with an image")
    img = nodes[0].image
    name = bpy.path.basename(img.filepath) or f"{img.name}.png"
    if img.packed_file is not None and not img.is_dirty:
        return name, bytes(img.packed_file.data)
    path = bpy.path.abspath(img.filepath) if img.filepath else ""
    if path and os.path.isfile(path) and not img.is_dirty:
        with open(path, "rb") as fh:
            return name, fh.read()
    with tempfile.TemporaryDirectory() as tmp:  # generated or painted in Blender: its pixels as a PNG
        out = os.path.join(tmp, "photo.png")
        img.save_render(out, scene=bpy.context.scene)
        with open(out, "rb") as fh:
            return f"{img.name}.png", fh.read()


class PROCTEX_OT_photo_look(bpy.types.Operator):
    """Send the active object's image texture to the service as a part's photo: a new look of the family"""

    bl_idname = "proctex.photo_look"
    bl_label = "Photo look from image"

    def execute(self, context):
        settings = context.scene.proctex
        if not settings.family:
            self.report({"ERROR"}, "pick a family first (Refresh families)")
            return {"CANCELLED"}
        if not settings.token:
            self.report({"ERROR"}, "a new look needs the service's edit token")
            return {"CANCELLED"}
        try:
            filename, data = active_image(context.active_object)
        except ValueError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        part = settings.photo_part.strip() or "*"
        extra = {part: {"scale": settings.photo_scale.strip()}} if settings.photo_scale.strip() else None
        url, name, token, look = settings.url, settings.family, settings.token, settings.photo_look.strip()
        settings.status = f"painting look {look} from {filename}..."
        _start("photo_look", lambda: client.add_photo_look(url, name, token, look, {part: (filename, data)}, settings=extra), url=url, family=name, scene=context.scene.name)
        return {"FINISHED"}


class PROCTEX_OT_add_variant(bpy.types.Operator):
    """Add the family's shape at the panel's parameters, textured, at the 3D cursor"""

    bl_idname = "proctex.add_variant"
    bl_label = "Add variant"

    def execute(self, context):
        settings = context.scene.proctex
        if not settings.family or not settings.accepts_params:
            self.report({"ERROR"}, "this family takes meshes only; use Texture selected")
            return {"CANCELLED"}
        params = {p.name: p.value() for p in settings.params}
        url, name, seed, look = settings.url, settings.family, settings.seed, settings.look or None
        settings.status = "making a variant..."
        _start("glb", lambda: client.transfer_params(url, name, params, seed, look=look), family=name, scene=context.scene.name)
        return {"FINISHED"}


class PROCTEX_PT_panel(bpy.types.Panel):
    bl_label = "ProcTex"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "ProcTex"

    def draw(self, context):
        settings = context.scene.proctex
        col = self.layout.column()
        col.prop(settings, "url")
        row = col.row(align=True)
        row.prop(settings, "family")
        row.operator("proctex.refresh", text="", icon="FILE_REFRESH")
        col.prop(settings, "look")
        if settings.accepts_params:
            box = col.box()
            for p in settings.params:
                slot = {"continuous": "value_float", "integer": "value_int"}.get(p.kind, "value_choice")
                box.prop(p, slot, text=p.name)
        col.prop(settings, "seed")
        col.operator("proctex.texture_selected")
        col.operator("proctex.add_variant")
        box = col.box()
        box.label(text="A look from the active object's image")
        box.prop(settings, "token")
        box.prop(settings, "photo_look")
        box.prop(settings, "photo_part")
        box.prop(settings, "photo_scale")
        box.operator("proctex.photo_look")
        if settings.status:
            col.label(text=settings.status)


CLASSES = (ProcTexParam, ProcTexSettings, PROCTEX_OT_refresh, PROCTEX_OT_texture_selected, PROCTEX_OT_add_variant, PROCTEX_OT_photo_look, PROCTEX_PT_panel)


def register() -> None:
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.Scene.proctex = PointerProperty(type=ProcTexSettings)


def unregister() -> None:
    if bpy.app.timers.is_registered(drain):
        bpy.app.timers.unregister(drain)
    del bpy.types.Scene.proctex
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
