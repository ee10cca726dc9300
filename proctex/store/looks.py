"""A family's looks: the same geometry (samples, template, grouping, UVs, pairs, networks) painted
more than one way. The build's look lies in ``template/`` (named ``default`` unless its paint record
says otherwise); every other look in ``looks/<name>/`` with its record ``look.json`` (its paint
settings, when it was made), written last. Stores made before looks read as one look, ``default``,
unchanged on disk."""

from __future__ import annotations

from dataclasses import asdict, replace
from typing import Any

from proctex.store.layout import (
    DEFAULT_LOOK,
    FamilyStore,
    LookLayout,
    StoreLayout,
    check_look_name,
)
from proctex.texture.painting import PaintConfig


class UnknownLook(ValueError):
    """A look the family does not have (the message lists those it has)."""


def built_look(store: FamilyStore) -> LookLayout:
    """The build's look (``template/``), named as its paint record says (``default`` for stores
    made before looks)."""
    name = DEFAULT_LOOK
    if store.exists(StoreLayout.PAINT):
        try:
            name = str(store.read_json(StoreLayout.PAINT).get("look") or DEFAULT_LOOK)
        except (ValueError, AttributeError):
            name = DEFAULT_LOOK  # a damaged record is reported where it is read for its textures
    return StoreLayout.look(name, built=True)


def other_looks(store: FamilyStore) -> list[LookLayout]:
    """The finished looks besides the build's (``looks/<name>/`` with its ``look.json``), by name."""
    out = []
    for name in sorted(store.listdir(StoreLayout.LOOKS)):
        try:
            look = StoreLayout.look(name)
        except ValueError:
            continue  # a staging folder or a stray name
        if store.exists(look.RECORD):
            out.append(look)
    return out


def looks(store: FamilyStore) -> list[LookLayout]:
    """Every look of the family: the build's first, then the others by name."""
    first = built_look(store)
    return [first] + [lk for lk in other_looks(store) if lk.name != first.name]


def resolve_look(store: FamilyStore, name: str | None = None) -> LookLayout:
    """The look called ``name`` (None: the build's); :class:`UnknownLook` listing the family's
    looks when there is none of that name."""
    first = built_look(store)
    if name is None or name == first.name:
        return first
    check_look_name(name)
    look = StoreLayout.look(name)
    if not store.exists(look.RECORD):
        raise UnknownLook(f"unknown look {name!r}; the family's looks are: {', '.join(lk.name for lk in looks(store))}")
    return look


def look_paint(store: FamilyStore, look: LookLayout, build_paint: PaintConfig) -> PaintConfig:
    """The paint settings of ``look``: the build's (``build_paint``) for the build's look, else
    those its ``look.json`` recorded."""
    if look.built:
        return build_paint
    record = store.read_json(look.RECORD)
    paint = record.get("paint") if isinstance(record, dict) else None
    if not isinstance(paint, dict):
        raise ValueError(f"{store.path(look.RECORD)}: a look record without its paint settings")
    return PaintConfig(**paint).validate()


def look_summary(store: FamilyStore, look: LookLayout, build_paint: PaintConfig) -> dict[str, Any]:
    """JSON-ready: ``name``, ``built`` (the build's look), ``prompt``, ``painter``, ``texture_size``,
    ``group_prompts``, ``part_words``, ``edits`` and, for an added look, when it was made and how long it took."""
    paint = look_paint(store, look, build_paint)
    record = {} if look.built else store.read_json(look.RECORD)
    summary = store.read_json(look.PAINT) if store.exists(look.PAINT) else {}
    return {
        "name": look.name,
        "built": look.built,
        "prompt": paint.prompt,
        "painter": paint.painter,
        "texture_size": paint.texture_size,
        "group_prompts": dict(paint.group_prompts),
        "part_words": dict(paint.part_words),
        "edits": len(summary.get("edits", [])),
        **{k: record[k] for k in ("made", "seconds") if k in record},
    }


def new_look_paint(
    build_paint: PaintConfig,
    prompt: str | None,
    group_prompts: dict[str, str] | None = None,
    painter: str | None = None,
    texture_size: int | None = None,
    part_words: dict[str, str] | None = None,
    images: dict[str, dict[str, Any]] | None = None,
    glb: dict[str, Any] | None = None,
) -> PaintConfig:
    """The paint settings of a new look: the build's (views, fill, ...) with ``prompt`` and, where
    given, ``painter`` and ``texture_size`` over them; group prompts only those given (the build's
    belong to its prompt); part words (the user's word per group) those given over the build's
    (:func:`proctex.looks.add_look` lays the family's stored ones between). ``images``: a look
    from photos (:attr:`PaintConfig.images`); it paints with the surface painter, and without a
    ``prompt`` keeps the build's (for the groups no photo covers and every group's metalness).
    ``glb``: a look read from a repainted template GLB (its name and checksum, for the record).
    Checked (``ValueError``)."""
    if prompt is None and not images and not glb:
        raise ValueError("a new look needs a prompt, photos, or both (or a repainted template GLB)")
    over: dict[str, Any] = {
        "prompt": build_paint.prompt if prompt is None else prompt,
        "group_prompts": dict(group_prompts or {}),
        "part_words": {**build_paint.part_words, **{str(k): v for k, v in (part_words or {}).items()}},
    }
    if painter is not None:
        over["painter"] = painter
    if texture_size is not None:
        over["texture_size"] = texture_size
    over["images"] = dict(images or {})
    over["glb"] = dict(glb or {})
    if images and painter is None:
        over["painter"] = "surface"
    return replace(build_paint, **over).validate()


def paint_record(paint: PaintConfig) -> dict[str, Any]:
    """The paint settings as a look record keeps them."""
    return asdict(paint)
