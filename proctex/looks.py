"""Looks of a built family (:mod:`proctex.store.looks`): a new prompt painted on the stored template,
its grouping and UVs, in seconds; nothing else of the family is touched (no sampling, no pairs, no
training: correspondence does not depend on the prompt)."""

from __future__ import annotations

import json
import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from proctex.geometry.meshio import load_mesh_bytes
from proctex.geometry.shape import Shape
from proctex.store.config import BuildConfig
from proctex.store.family import Family
from proctex.store.layout import FamilyStore, LookLayout, MAP_KINDS, StoreLayout, check_look_name, digest, encode_arrays
from proctex.store.locks import StoreBusy, store_lock
from proctex.store.looks import built_look, look_paint, looks as family_looks, paint_record, resolve_look
from proctex.store.networks import load_models
from proctex.store.partwords import stored_part_words
from proctex.store.state import Changed, FamilyState
from proctex.store.template import TemplateFiles, encode_textures, load_template_shape, write_textured
from proctex.texture.exemplar import layers
from proctex.texture.fromglb import glb_frame, textures_from_glb
from proctex.texture.gltf_read import read_textured_glb
from proctex.texture.paint_loop import paint_with
from proctex.texture.painters.partwords import check_assignment, parts_report
from proctex.texture.painting import PaintConfig
from proctex.texture.pbr import PbrMaps
from proctex.texture.uv import Atlas, ShapeUV
from proctex.transfer.assets import load_assets
from proctex.transfer.budget import Budget
from proctex.transfer.frommember import member_surface, textures_from_member
from proctex.transfer.methods import get_method, make_mapper


class LookOverLimit(ValueError):
    """A look refused by :class:`LookLimits` before it was written: ``kind`` "size" (texels, bytes)
    or "count" (the family holds its most looks)."""

    def __init__(self, message: str, kind: str) -> None:
        super().__init__(message)
        self.kind = kind


@dataclass(frozen=True)
class LookLimits:
    """What one look may cost, the same from the command line and over HTTP (the service's
    ``Limits.look_*`` set them there): ``seconds`` of painting start to files (None: no limit;
    :class:`proctex.transfer.budget.Budget`: cancelled or past it, nothing is written), ``texels``
    (texture side squared times the family's groups, checked before any work), ``bytes`` of the
    look's files (checked once encoded, before anything is written) and ``looks`` per family (the
    build's not counted; a look replaced with ``force`` not counted twice). The defaults take a
    2048² look of 8 groups (about 100 MB and 100 s on 2 cores)."""

    seconds: float | None = 600.0
    texels: int = 8 * 2048 * 2048
    bytes: int = 256 * 2**20
    looks: int = 64

    def __post_init__(self) -> None:
        if self.seconds is not None and not (isinstance(self.seconds, (int, float)) and not isinstance(self.seconds, bool) and 0 < self.seconds < float("inf")):
            raise ValueError(f"look seconds must be a positive number (or None), got {self.seconds!r}")
        for name in ("texels", "bytes", "looks"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"look {name} must be a positive integer, got {value!r}")

    def check_start(self, store: FamilyStore, name: str, paint: PaintConfig, force: bool) -> None:
        """:class:`LookOverLimit` for a look over the family's count or the texel bound, before any work."""
        others = [lk for lk in family_looks(store) if not lk.built and not (force and lk.name == name)]
        if len(others) >= self.looks:
            raise LookOverLimit(f"the family has {len(others)} looks, its most ({self.looks}); remove one first (proctex look rm FAMILY NAME)", "count")
        groups = len(store.read_json(StoreLayout.PAINT).get("groups", [])) if store.exists(StoreLayout.PAINT) else 1
        texels = int(paint.texture_size) ** 2 * max(groups, 1)
        if texels > self.texels:
            raise LookOverLimit(f"a look of {groups} groups at {paint.texture_size}² is {texels} texels, over the limit of {self.texels}", "size")


def stored_uv(files: TemplateFiles, shape: Any, grouping: Any, resolution: int) -> Any:
    """The template's stored UVs as a :class:`proctex.texture.uv.ShapeUV` (a look paints into the
    layout the build made: its GLB geometry and UVs stay byte for byte the build's)."""
    corner_uv, face_group = files.corner_uv(), files.face_group()
    if corner_uv.shape != (shape.n_faces, 3, 2) or face_group.shape != (shape.n_faces,):
        raise ValueError(f"{files.store.uri}: the stored UVs do not match the template mesh")
    recorded = {int(g["group"]): g for g in files.summary.get("groups", [])}
    atlases = []
    for g in grouping.groups:
        rep = grouping.parts[g.representative]
        entry = recorded.get(g.index, {})
        atlases.append(Atlas(corner_uv[rep.faces], str(entry.get("atlas", "stored")), int(entry.get("charts", 0)), resolution, 0, 0.0))
    return ShapeUV(corner_uv, face_group, atlases, resolution)


def look_files(
    store: FamilyStore,
    config: BuildConfig,
    paint: PaintConfig,
    look: LookLayout,
    state: FamilyState | None = None,
    log: Callable[[str], None] = print,
    photos: dict[str, Any] | None = None,
    glb: bytes | None = None,
    member: dict[str, Any] | None = None,
    check: Callable[[str], None] | None = None,
) -> tuple[list[tuple[str, bytes]], dict[str, Any]]:
    """Paint the stored template with ``paint`` and return the files of ``look`` (paths relative to
    the store, ``look.json`` last) and its record. ``photos``: the
    :class:`proctex.texture.exemplar.Photo` of each ``paint.images`` key (a look from photos; read
    from the entries' files where missing): each is kept in the look as ``photo-<i>.png`` and its
    entry names that file. ``check(what)`` between the steps (and each group's painting) may raise
    to stop (a budget). Nothing is written."""
    check = check if check is not None else (lambda what: None)

    t0 = time.perf_counter()
    state = state if state is not None else FamilyState.load(store)
    shape = load_template_shape(store, config, state)
    files = TemplateFiles(store, built_look(store))
    grouping = files.grouping(shape, seed=config.seed)
    uv = stored_uv(files, shape, grouping, paint.texture_size)
    kept: list[tuple[str, bytes]] = []
    if paint.images:
        from dataclasses import replace

        read = {k: v.photo for k, v in layers(paint.images, photos).items()}
        images = {}
        for i, (key, entry) in enumerate(paint.images.items()):
            png = read[key].png()
            kept.append((look.file(f"photo-{i}.png"), png))
            images[key] = {**entry, "file": look.file(f"photo-{i}.png"), "sha256": digest(png), "name": read[key].name, "notes": list(read[key].notes)}
        paint, photos = replace(paint, images=images).validate(), read
    check("reading the template")
    if member is not None:
        tex, report = member_texture(store, files, shape, grouping, uv, paint.texture_size, member["glb"], member.get("params"), config)
        paint = replace_settings(paint, glb={**paint.glb, "member": True, "filled_share": round(report.filled_share, 4)})
    elif glb is not None:
        tex = glb_texture(store, files, shape, grouping, uv, paint.texture_size, glb, config.up_axis())
        paint = replace_settings(paint, glb={**paint.glb, "faces": len(shape.faces), "extra_triangles": tex.stats["extra_triangles"]})
    else:
        tex = paint_with(
            shape,
            grouping,
            paint,
            seed=config.seed,
            up=config.up_axis(),
            uv=uv,
            photos=photos,
            check=check,
            on_view=lambda k, n, st: log(f"look {look.name}: view {k + 1}/{n}, {st['texels_updated']} texels"),
        )
    check("encoding the look's images")
    encoded = encode_textures(tex)
    check("writing the look's files")
    out: list[tuple[str, bytes]] = list(kept)
    with tempfile.TemporaryDirectory() as tmp:
        summary = write_textured(tex, tmp, up=config.up_axis(), encoded=encoded)
        for name in sorted(os.listdir(tmp)):
            if name != StoreLayout.PAINT_NAME:
                out.append((look.file(name), (Path(tmp) / name).read_bytes()))
    pngs, maps = encoded
    for entry, png, m in zip(summary["groups"], pngs, maps):  # the record keeps each file's checksum
        entry["sha256"] = digest(png)
        if m is not None:
            entry.update({f"{kind}_sha256": digest(getattr(m, kind)) for kind in MAP_KINDS}, occlusion=bool(m.occlusion))
    summary["files"] = [look.file(os.path.basename(f)) for f in summary.get("files", [])]
    summary["look"] = look.name
    masks = {f"g{k}": m for k, m in enumerate(tex.painted_masks)}
    masks.update({f"o{k}": m for k, m in enumerate(tex.observed_masks or tex.painted_masks)})
    out.append((look.PAINTED, encode_arrays(**{k: np.asarray(v, dtype=bool) for k, v in masks.items()})))
    out.append((look.PAINT, json.dumps(summary, indent=1).encode() + b"\n"))
    record = {"name": look.name, "paint": paint_record(paint), "made": time.strftime("%Y-%m-%dT%H:%M:%S"), "seconds": round(time.perf_counter() - t0, 3), "coverage": summary["coverage"]["share"]}
    out.append((look.RECORD, json.dumps(record, indent=1).encode() + b"\n"))
    return out, record


def replace_settings(paint: PaintConfig, **over: Any) -> PaintConfig:
    """``paint`` with the fields ``over`` replaced, checked (``ValueError``)."""
    from dataclasses import replace

    return replace(paint, **over).validate()


def _base_maps(files: TemplateFiles, grouping: Any, size: int) -> list:
    """Per group the build look's PBR maps at ``size`` (None where it has none): what a look read from
    a file keeps where the file brings no maps."""
    import io

    from PIL import Image

    base = []
    for g in grouping.groups:
        orm, normal = files.map_png(g.index, "orm"), files.map_png(g.index, "normal")
        if orm is None or normal is None:
            base.append(None)
            continue
        read = [np.asarray(Image.open(io.BytesIO(b)).convert("RGB").resize((size, size)), dtype=np.float32) / 255.0 for b in (orm, normal)]
        base.append(PbrMaps(read[0], read[1], bool(files.group(g.index).get("occlusion", False))))
    return base


def member_texture(store: FamilyStore, files: TemplateFiles, shape: Any, grouping: Any, uv: Any, size: int, data: bytes, params: dict[str, Any] | None, config: BuildConfig) -> tuple[Any, Any]:
    """The look a textured member GLB (``data``) holds (:func:`proctex.transfer.frommember.textures_from_member`),
    mapped as the service maps shapes (the group networks where trained, ``auto``): with ``params``
    the family's own shape for them, else the file read as ``proctex transfer --mesh`` reads it."""
    glb = read_textured_glb(data)
    up = config.up_axis()
    if params is not None:
        member = config.procedural_model().generate(params)
        what = "the family's shape for these parameters"
    else:  # read as `proctex transfer --mesh` reads it (its parts as a transfer finds them), turned into the family's frame
        from dataclasses import replace

        read, _ = load_mesh_bytes(data, "member.glb")
        turn = glb_frame(np.eye(3), up)  # the turn as a matrix applied to rows (v @ turn); its transpose turns the file back
        member = replace(read, vertices=read.vertices @ turn.T)
        what = "a mesh of the family's kind"
    member_uv, material, _ = member_surface(member, glb_frame(member.vertices, up), glb, what)
    state = FamilyState.load(store)
    assets = load_assets(store, state, built_look(store))
    models = load_models(store, "cpu", state) if get_method("auto").networks != "none" else {}
    mapper = make_mapper("auto", assets, models, corr_points=config.corr_points, cage=config.cage)
    tex, report = textures_from_member(shape, grouping, uv, assets, member, member_uv, material, glb.textures, mapper, size, seed=config.seed, base_maps=_base_maps(files, grouping, size))
    tex.notes.extend(f"member: group {g} {100 * f:.1f}% of its texels filled from neighbours" for g, f in report.filled.items())
    return tex, report


def glb_texture(store: FamilyStore, files: TemplateFiles, shape: Any, grouping: Any, uv: Any, size: int, data: bytes, up: str) -> Any:
    """The look a repainted template GLB (``data``) holds (:func:`proctex.texture.fromglb.textures_from_glb`),
    the build's maps kept where the file's materials have none; the template ``shape`` back in its
    own frame in the result."""
    glb = read_textured_glb(data)
    turned = Shape(glb_frame(shape.vertices, up), shape.faces)
    tex, match, notes = textures_from_glb(turned, grouping, uv, glb, size, _base_maps(files, grouping, size))
    tex.shape = shape
    tex.stats["extra_triangles"] = match.extra
    tex.notes.extend(notes)
    return tex


def add_look(store: FamilyStore, name: str, paint: PaintConfig, **how: Any) -> dict[str, Any]:
    """:func:`changed_look`'s record: the new look's, as the command line and the library make it."""
    return changed_look(store, name, paint, **how).record


def changed_look(
    store: FamilyStore,
    name: str,
    paint: PaintConfig,
    force: bool = False,
    log: Callable[[str], None] = print,
    timeout: float = 60.0,
    photos: dict[str, Any] | None = None,
    glb: bytes | None = None,
    member: dict[str, Any] | None = None,
    limits: LookLimits | None = None,
    budget: Any = None,
) -> Changed:
    """Paint look ``name`` of the built family in ``store`` with ``paint`` (and the family's stored
    part words, :func:`with_stored_words`) and store it in ``looks/<name>/`` as one change (staged
    beside it, then put in place: a reader sees the whole look or none). ``force`` replaces a look of that name. Refused while a build of the store runs;
    waits up to ``timeout`` s for an edit or another look being written. ``photos``: a look from
    photos' images already read; ``glb``: a repainted template GLB's bytes; ``member``: a textured
    member's (:func:`look_files`). ``limits`` (default :class:`LookLimits`): the look's count and
    texels are checked before any work, its time while it paints (``budget``, a
    :class:`proctex.transfer.budget.Budget` the caller may cancel, default one of ``limits.seconds``)
    and its bytes before anything is written (:class:`LookOverLimit`, or
    :class:`~proctex.transfer.budget.OverBudget`: nothing written either way).
    Returns the look's record and the family's version after it, read under the lock it was written
    under (:class:`~proctex.store.state.Changed`)."""
    check_look_name(name)
    paint = paint.validate()
    limits = limits if limits is not None else LookLimits()
    budget = budget if budget is not None else Budget(limits.seconds)
    state = FamilyState.load(store)
    config = state.build_config(store.uri)
    if not (state.done("template") and state.done("paint")):
        raise ValueError(f"{store.uri}: the family's template is not painted yet (build it first: proctex build)")
    if name == built_look(store).name:
        raise ValueError(f"{name!r} is the build's look; give the new look another name (or edit this one: proctex edit)")
    look = StoreLayout.look(name)
    if store.exists(look.RECORD) and not force:
        raise ValueError(f"the family has a look {name!r} already; --force replaces it")
    paint = with_stored_words(store, config.paint, paint)
    limits.check_start(store, name, paint, force)
    with store_lock(store, StoreLayout.BUILD_LOCK, f"adding look {name}", shared=True, busy=StoreBusy, note=True):
        files, record = look_files(store, config, paint, look, state, log, photos=photos, glb=glb, member=member, check=budget.check)
        size = sum(len(data) for _, data in files)
        if size > limits.bytes:
            raise LookOverLimit(f"look {name!r} came to {size} bytes of files, over the limit of {limits.bytes}; nothing was written", "size")
        budget.check("writing the look")
        with store_lock(store, StoreLayout.EDIT_LOCK, f"adding look {name}", timeout=timeout, busy=StoreBusy):
            limits.check_start(store, name, paint, force)  # another look may have landed meanwhile
            if store.exists(look.RECORD) and not force:
                raise ValueError(f"the family has a look {name!r} already (made meanwhile); --force replaces it")
            store.replace_folder(look.folder, files)
            version = Family.open(store).version
    log(f"look {name}: {len(files)} files in {look.folder}/, {record['seconds']:.1f} s")
    return Changed(record, version)


def with_stored_words(store: FamilyStore, build_paint: PaintConfig, paint: PaintConfig) -> PaintConfig:
    """``paint`` with the family's stored part words (:mod:`proctex.store.partwords`: the user's
    last word, saved after the build) laid over the build's, and those ``paint`` names beyond the
    build's over both."""
    from dataclasses import replace

    stored = stored_part_words(store)
    if not stored:
        return paint
    own = {k: v for k, v in paint.part_words.items() if build_paint.part_words.get(k) != v}
    return replace(paint, part_words={**build_paint.part_words, **stored, **own}).validate()


def remove_look(store: FamilyStore, name: str, timeout: float = 60.0) -> None:
    """Delete look ``name`` (not the build's look). ``UnknownLook`` when there is none."""
    look = resolve_look(store, name)
    if look.built:
        raise ValueError(f"{name!r} is the build's look: it cannot be removed (its family would have none)")
    with store_lock(store, StoreLayout.EDIT_LOCK, f"removing look {name}", timeout=timeout, busy=StoreBusy):
        store.delete(look.RECORD)  # first: the look is gone for readers before its files are
        store.delete(look.folder)


def name_built_look(store: FamilyStore, name: str, timeout: float = 60.0) -> str:
    """Call the build's look (``template/``) ``name`` (``proctex build --look NAME``; ``default``
    until named). ``ValueError`` when the family has another look of that name or is not painted
    yet. Returns the name it had."""
    check_look_name(name)
    with store_lock(store, StoreLayout.EDIT_LOCK, f"naming the build's look {name}", timeout=timeout, busy=StoreBusy):
        if not store.exists(StoreLayout.PAINT):
            raise ValueError(f"{store.uri}: the family's template is not painted yet")
        if store.exists(StoreLayout.look(name).RECORD):
            raise ValueError(f"the family has another look called {name!r} (looks/{name}/): choose another name for the build's look")
        summary = store.read_json(StoreLayout.PAINT)
        before = str(summary.get("look") or built_look(store).name)
        if before != name:
            summary["look"] = name
            store.write_json(StoreLayout.PAINT, summary)
    return before


def family_parts(store: FamilyStore, prompt: str | None = None, look: str | None = None, assign: dict[str, str] | None = None) -> tuple[dict[str, Any], tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """What the part words of ``prompt`` (default: the prompt of ``look``, the build's look when
    None) do on the family's template (:func:`proctex.texture.painters.partwords.parts_report`),
    with the family's stored words (:mod:`proctex.store.partwords`) over the look's and ``assign``
    over both; adds ``family``, ``look``, ``stored`` (the stored words) and ``up``. Also returns the
    template's vertices, faces and face groups for a picture: ``(report, (vertices, faces,
    face_group))``. Nothing is written."""
    state = FamilyState.load(store)
    config = state.build_config(store.uri)
    if not state.done("template"):
        raise ValueError(f"{store.uri}: the family has no template yet (build it first: proctex build)")
    found = resolve_look(store, look)
    paint = look_paint(store, found, config.paint)
    text = paint.prompt if prompt is None else prompt
    if not isinstance(text, str):
        raise ValueError(f"prompt must be a string, got {type(text).__name__}")
    shape = load_template_shape(store, config, state)
    grouping = TemplateFiles(store, built_look(store)).grouping(shape, seed=config.seed)
    stored = stored_part_words(store)
    given = {str(k): v for k, v in check_assignment(assign or {}, len(grouping.groups)).items()}
    words = {**paint.part_words, **stored, **given}
    report = parts_report(text, shape.vertices, shape.faces, grouping, config.up_axis(), assigned=words)
    face_group = np.full(shape.n_faces, -1, dtype=np.int64)
    for p in grouping.parts:
        face_group[p.faces] = int(grouping.part_group[p.index])
    report = {"family": store.uri, "look": found.name, "up": config.up_axis(), "stored": stored, **report}
    return report, (shape.vertices, shape.faces, face_group)
