"""Edits of a built family's template textures (re-paint, HSV shift, an image placed at a UV spot):
they change the store, so every later transfer shows them."""

from __future__ import annotations

import contextlib
import math
import os
import time
from typing import Any, Callable, TypeVar

import numpy as np

from proctex.fileio import encode_png
from proctex.geometry.shape import Shape
from proctex.store.family import Family
from proctex.store.layout import FamilyStore, StoreDamaged, StoreLayout
from proctex.store.leases import StoreChanged, supports_leases
from proctex.store.locks import is_local, store_lock
from proctex.store.looks import resolve_look
from proctex.store.state import Changed, stored_config
from proctex.store.template import TemplateFiles, decode_png, load_template_shape, png_size
from proctex.texture.edit import load_overlay, place_image, shift_hsv
from proctex.texture.paint import shape_frame
from proctex.texture.painters import SurfacePainter
from proctex.texture.pbr import bake_maps
from proctex.texture.uv import pad_seams, texel_map

T = TypeVar("T")


def repaint_maps(prompt: str, group: int, label: str | None, template: Shape, rep_faces: np.ndarray, rep_corner_uv: np.ndarray, size: tuple[int, int], seed: int = 0) -> Any:
    """The PBR maps (:class:`proctex.texture.pbr.PbrMaps`, float) of a group re-painted with ``prompt``:
    what :func:`edit_texture` does for the colour, for roughness, metalness and relief (the surface
    painter bound to the template, so the prompt's regions apply in the part's own frame)."""
    faces = template.faces[np.asarray(rep_faces)]
    tm = texel_map(template.vertices, faces, np.asarray(rep_corner_uv), size[0], size[1])
    center, scale = shape_frame(template)
    painter = SurfacePainter(prompt, seed=seed)

    def props(p, n, t, b):
        return painter.material(p, n, t, b, group=int(group), label=label or "")

    return bake_maps(tm, template.vertices, faces, np.asarray(rep_corner_uv), props, center, scale)


def add_material_maps(store: FamilyStore, force: bool = False) -> list[int]:
    """Give a family painted before PBR maps were made its maps, from each group's stored prompt (the
    family's prompt, group prompts and re-paints as ``template/paint.json`` records them) on the stored
    template, under the family's edit lock. Groups that have maps keep them unless ``force``. The
    textures, UVs and networks are untouched, so transfers keep their colours and gain the maps.
    Returns the groups that got maps."""
    with edit_lock(store):
        config = stored_config(store)
        template = load_template_shape(store, config)
        files = TemplateFiles(store)
        grouping = files.grouping(template, config.seed)
        uv = files.corner_uv()
        made = []
        for entry in files.summary["groups"]:
            gi = int(entry["group"])
            if entry.get("orm_sha256") and not force:
                continue
            rep = grouping.parts[grouping.groups[gi].representative].faces
            prompt = entry.get("prompt") or config.paint.prompt
            hw = png_size(files.texture_png(gi), f"group {gi}'s texture")
            maps = repaint_maps(prompt, gi, entry["label"], template, rep, uv[rep], hw, seed=config.seed)
            files.commit(gi, maps={"orm": encode_png(maps.orm_uint8()), "normal": encode_png(maps.normal_uint8())}, occlusion=False, versioned=False, glb=(template, config.up_axis()))
            made.append(gi)
        return made


def adjust_orm(orm: np.ndarray, roughness: float | None = None, metallic: float | None = None, mask: np.ndarray | None = None) -> np.ndarray:
    """An ORM image (H, W, 3, uint8 or float in [0, 1]) with its roughness (G) and metalness (B)
    moved to the given means over ``mask`` ((H, W) bool: the painted texels; default all): the
    channel is shifted by the difference, so its variation (grain, rust patches) stays, and clipped
    to [0, 1]. Occlusion (R) is untouched. Returns float32."""
    a = np.asarray(orm)
    out = (a.astype(np.float32) / 255.0) if a.dtype == np.uint8 else a.astype(np.float32, copy=True)
    sel = np.ones(out.shape[:2], bool) if mask is None or np.shape(mask) != out.shape[:2] or not np.any(mask) else np.asarray(mask, bool)
    for channel, target in ((1, roughness), (2, metallic)):
        if target is None:
            continue
        if isinstance(target, bool) or not (isinstance(target, (int, float)) and np.isfinite(target) and 0.0 <= target <= 1.0):
            raise ValueError(f"{('roughness', 'metallic')[channel - 1]} must be a number in [0, 1], got {target!r}")
        c = out[..., channel]
        out[..., channel] = np.clip(c + (float(target) - float(c[sel].mean())), 0.0, 1.0)
    return out


def edit_texture(
    texture: np.ndarray,
    group: int,
    label: str | None = None,
    hue: float = 0.0,
    saturation: float = 1.0,
    value: float = 1.0,
    prompt: str | None = None,
    template: Shape | None = None,
    rep_faces: np.ndarray | None = None,
    rep_corner_uv: np.ndarray | None = None,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray | None, dict[str, Any]]:
    """One group texture after an edit: re-painted with ``prompt`` first (the surface painter,
    ``seed``), then HSV-shifted (``hue`` degrees, ``saturation`` and ``value`` scales). Pure: the
    store is not touched (:func:`edit_group` persists, the service previews with it).

    Args:
        texture: (H, W, 3) uint8 or float in [0, 1], the group's current texture.
        group, label: the group (the painter takes them as hints).
        template, rep_faces, rep_corner_uv: needed for a re-paint only: the template shape, the face
            ids of the group's representative part and their (f, 3, 2) UVs.

    Returns:
        ``(texture, painted, record)``: (H, W, 3) float32 in [0, 1]; the (H, W) bool mask of the texels
        the re-paint coloured (None without a prompt); the edit record (``group``, ``prompt``,
        ``hsv`` as given, without the operations that were no-ops).
    """
    t = np.asarray(texture)
    tex = (t.astype(np.float32) / 255) if t.dtype == np.uint8 else t.astype(np.float32)
    tex = np.ascontiguousarray(tex[..., :3])
    record: dict[str, Any] = {"group": int(group)}
    painted = None
    if prompt is not None:
        if template is None or rep_faces is None or rep_corner_uv is None:
            raise ValueError("a re-paint needs the template, its representative faces and their UVs")
        faces = template.faces[np.asarray(rep_faces)]
        tm = texel_map(template.vertices, faces, np.asarray(rep_corner_uv), tex.shape[0], tex.shape[1])
        center, scale = shape_frame(template)
        colors = SurfacePainter(prompt, seed=seed).paint((tm.points - center) / scale, tm.normals, group=int(group), label=label)
        fresh = np.full_like(tex, 0.5)
        fresh[tm.ij[:, 0], tm.ij[:, 1]] = colors
        tex, painted = pad_seams(fresh, tm.mask, 8)
        tex = np.asarray(tex, dtype=np.float32)
        record["prompt"] = prompt
    if hue or saturation != 1.0 or value != 1.0:
        tex = shift_hsv(np.clip(tex, 0, 1), hue_deg=hue, saturation=saturation, value=value)
        record["hsv"] = [hue, saturation, value]
    return tex, painted, record


def check_placement(at: Any, size: Any, rotation: Any, opacity: Any) -> None:
    """``ValueError`` unless an image placement is meaningful: ``at`` two UV coordinates in [0, 1],
    ``size`` two UV extents in (0, 1], ``rotation`` a finite number of degrees, ``opacity`` in [0, 1]."""

    def pair(name: str, v: Any, lo: float, hi: float, open_low: bool) -> None:
        ok = (
            isinstance(v, (tuple, list))
            and len(v) == 2
            and all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and (lo < x if open_low else lo <= x) and x <= hi for x in v)
        )
        if not ok:
            raise ValueError(f"{name} must be two numbers in {'(' if open_low else '['}{lo:g}, {hi:g}] (UV units), got {str(v)[:60]}")

    pair("at", at, 0.0, 1.0, False)
    pair("size", size, 0.0, 1.0, True)
    if isinstance(rotation, bool) or not isinstance(rotation, (int, float)) or not math.isfinite(rotation):
        raise ValueError(f"rotation must be a finite number of degrees, got {str(rotation)[:40]}")
    if isinstance(opacity, bool) or not isinstance(opacity, (int, float)) or not 0.0 <= opacity <= 1.0:
        raise ValueError(f"opacity must be a number in [0, 1], got {str(opacity)[:40]}")


def changed_edit(
    store: FamilyStore,
    group: int | str,
    hue: float = 0.0,
    saturation: float = 1.0,
    value: float = 1.0,
    logo: str | None = None,
    at: tuple[float, float] = (0.5, 0.5),
    size: tuple[float, float] = (0.25, 0.25),
    rotation: float = 0.0,
    opacity: float = 1.0,
    prompt: str | None = None,
    roughness: float | None = None,
    metallic: float | None = None,
    expect_stamp: str | None = None,
    look: str | None = None,
) -> Changed:
    """Edit one group's template texture in the store; every later transfer or bake uses it. Every
    edit (the CLI's, the service's, the library's) is a new template version: under the family's
    edit lock, checked against ``expect_stamp`` (the family's version, :attr:`proctex.store.family.Family.version`,
    :class:`EditConflict` when they differ), built on files whose checksums hold (a file changed outside ProcTex is refused, never
    recorded), and written as one change with its undo snapshot (:meth:`TemplateFiles.commit`: a
    full disk leaves the family as it was).

    Operations, applied in this order when several are given: re-paint with a new ``prompt`` (the
    surface painter, the family's seed), HSV shift (``hue`` degrees, ``saturation`` and ``value``
    scales) — both by :func:`edit_texture` —, and placing an image file (``logo``) centred at UV
    ``at`` with UV ``size`` (each in (0, 1]), ``rotation`` (degrees) and ``opacity``. A re-paint
    makes the group's PBR maps again from the new prompt; an HSV shift or an image leaves them as
    they are; ``roughness`` / ``metallic`` move the group's roughness and metalness maps to those
    means (:func:`adjust_orm`). ``look``: the family's look to edit (default: the build's; each
    look keeps its own edits and undo history). Returns the edit record appended to the look's
    ``paint.json`` (its ``version`` and the digests of the group texture ``before`` and ``after``)
    and the family's version after it, read under the same lock (:class:`~proctex.store.state.Changed`).
    """
    if logo is not None:
        check_placement(at, size, rotation, opacity)
    with edit_lock(store):
        _expect(store, expect_stamp, "edit")
        record = _edit(store, group, hue, saturation, value, logo, at, size, rotation, opacity, prompt, roughness, metallic, look)
        return Changed(record, Family.open(store).version)


def edit_group(store: FamilyStore, group: int | str, **edit: Any) -> dict[str, Any]:
    """:func:`changed_edit`'s record: the edit, as the command line and the library make it."""
    return changed_edit(store, group, **edit).record


def _expect(store: FamilyStore, expect_stamp: str | None, what: str) -> None:
    """:class:`EditConflict` unless the family's version is ``expect_stamp`` (None: no condition);
    called under the edit lock."""
    if expect_stamp is not None:
        now = Family.open(store).version
        if now != expect_stamp:
            raise EditConflict(f"{store.uri} changed since stamp {expect_stamp!r} (now {now!r}); reload and {what} again")


def _edit(
    store: FamilyStore,
    group: int | str,
    hue: float,
    saturation: float,
    value: float,
    logo: str | None,
    at: Any,
    size: Any,
    rotation: float,
    opacity: float,
    prompt: str | None,
    roughness: float | None,
    metallic: float | None,
    look: str | None = None,
) -> dict[str, Any]:
    files = TemplateFiles(store, resolve_look(store, look))
    entry = files.group(group)
    gi = int(entry["group"])
    tex = files.texture(gi)
    template = rep_faces = rep_uv = None
    config = stored_config(store)
    if prompt is not None:  # the re-paint needs the template's geometry and its stored grouping
        template = load_template_shape(store, config)
        grouping = files.grouping(template, config.seed)
        rep_faces = grouping.parts[grouping.groups[gi].representative].faces
        rep_uv = files.corner_uv()[rep_faces]
    tex, painted, record = edit_texture(tex, gi, entry["label"], hue, saturation, value, prompt, template=template, rep_faces=rep_faces, rep_corner_uv=rep_uv, seed=config.seed)
    masks = files.painted_masks()
    if painted is not None and masks is not None:  # the whole group is painted now
        masks[f"g{gi}"] = painted
        masks[f"o{gi}"] = painted
    if logo is not None:
        tex = place_image(tex, load_overlay(logo), at, size, rotation_deg=rotation, opacity=opacity)
        record["logo"] = {"file": os.path.basename(logo), "at": list(at), "size": list(size), "rotation": rotation, "opacity": opacity}
    maps_out: dict[str, bytes] = {}
    if prompt is not None and entry.get("orm_sha256"):  # a re-paint makes every map again
        maps = repaint_maps(prompt, gi, entry["label"], template, rep_faces, rep_uv, tex.shape[:2], seed=config.seed)
        maps_out = {"orm": encode_png(maps.orm_uint8()), "normal": encode_png(maps.normal_uint8())}
    if roughness is not None or metallic is not None:
        if not entry.get("orm_sha256"):
            raise ValueError(f"group {gi} has no PBR maps (a family painted before they were made); re-paint it first")
        current = maps_out.get("orm") or files.map_png(gi, "orm")
        painted_mask = painted if painted is not None else (masks or {}).get(f"g{gi}")
        orm = adjust_orm(decode_png(current, f"group {gi}'s ORM map"), roughness, metallic, painted_mask)
        maps_out["orm"] = encode_png(orm)
        record["material"] = {k: v for k, v in (("roughness", roughness), ("metallic", metallic)) if v is not None}
    if len(record) == 1:
        raise ValueError("no edit given (prompt, hue/saturation/value, roughness/metallic or logo)")
    return files.commit(
        gi,
        record,
        texture=encode_png(tex),
        maps=maps_out,
        masks=masks if painted is not None else None,
        glb=(template if template is not None else load_template_shape(store, config), config.up_axis()),
    )


# ------------------------------------------------------------------------------ versioned edits
class EditConflict(ValueError):
    """The family changed since the stamp the edit was made against (or there is nothing to undo)."""


def edit_lock(store: FamilyStore, timeout: float = 60.0, shared: bool = False):
    """A context manager holding the family's edit lock, across processes on one machine
    (:func:`proctex.store.locks.store_lock` on ``.edit.lock``): exclusive for an edit, which also
    refuses to start while a build of the store runs (the build lock, shared), ``shared`` for a
    reader that must see the template's files of one version (a service loading the family). On an
    ``s3://`` store the locks are leases (:mod:`proctex.store.leases`), and a reader's block raises
    :class:`~proctex.store.leases.StoreChanged` when an edit ran while it read (read again:
    :func:`read_again`). Other object stores cannot be edited (``ValueError``); readers of them take
    no lock."""
    if not is_local(store) and not supports_leases(store):
        if shared:
            return contextlib.nullcontext()
        raise ValueError(f"{store.uri}: edits need a local folder or an s3:// store (locks by file locks or conditional writes)")
    if shared:
        return store_lock(store, StoreLayout.EDIT_LOCK, "a reader", shared=True, timeout=timeout, busy=EditConflict)

    @contextlib.contextmanager
    def both():
        with store_lock(store, StoreLayout.BUILD_LOCK, "an edit", shared=True, busy=EditConflict, note=True), store_lock(store, StoreLayout.EDIT_LOCK, "an edit", timeout=timeout, busy=EditConflict):
            yield

    return both()


def read_again(read: Callable[[], T], attempts: int = 8) -> T:
    """``read()`` (a reader of the store under ``edit_lock(shared=True)``), again while it raises
    :class:`~proctex.store.leases.StoreChanged` (an edit on an object store ran while it read), at
    most ``attempts`` times."""
    for attempt in range(attempts):
        try:
            return read()
        except StoreChanged:
            if attempt == attempts - 1:
                raise
            time.sleep(0.05 * (attempt + 1))
    raise AssertionError("unreachable")


def undo_edits(store: FamilyStore, expect_stamp: str | None = None, look: str | None = None, all_edits: bool = False) -> Changed:
    """Undo the last stored edit of the family's ``look`` (default: the build's; the files it
    replaced come back), or with ``all_edits`` every one, last first (the look as it was painted),
    under one edit lock; returns the undone records and the family's version after them
    (:class:`~proctex.store.state.Changed`). :class:`EditConflict` when ``expect_stamp`` is stale,
    or when there is no edit to undo (``all_edits``: nothing undone is no conflict)."""
    with edit_lock(store):
        _expect(store, expect_stamp, "undo")
        undone = []
        while True:
            files = TemplateFiles(store, resolve_look(store, look))
            if not files.edits:
                if not undone and not all_edits:
                    raise EditConflict(f"{store.uri}: no stored edit to undo")
                break
            config = stored_config(store)
            try:
                undone.append(files.undo(glb=(load_template_shape(store, config), config.up_axis())))
            except StoreDamaged:
                raise
            except ValueError as exc:
                raise EditConflict(str(exc)) from exc
            if not all_edits:
                break
        return Changed(undone, Family.open(store).version)


def undo_edit(store: FamilyStore, expect_stamp: str | None = None, look: str | None = None) -> dict[str, Any]:
    """The record of the last stored edit of ``look``, undone (:func:`undo_edits`)."""
    return undo_edits(store, expect_stamp, look).record[0]


def reset_edits(store: FamilyStore, look: str | None = None) -> list[dict[str, Any]]:
    """Undo every stored edit of ``look``, last first: the look as it was painted. Returns the undone records."""
    return undo_edits(store, look=look, all_edits=True).record
