"""The ``paint`` stage: parts, groups, UVs and one texture per group of the template into ``template/``."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Callable

from proctex.geometry.parts import analyse
from proctex.store.config import BuildConfig
from proctex.store.layout import FamilyStore, MAP_KINDS, StoreLayout
from proctex.store.state import stage_done
from proctex.store.template import StoredImages, StoredMaps, Template, encode_textures, load_template_shape, write_textured
from proctex.texture.paint_loop import paint_with
from proctex.texture.uv import source_uv


def paint_step(store: FamilyStore, config: BuildConfig, log: Callable[[str], None] = print) -> dict[str, Any] | None:
    """Parts, groups, UVs and textures of the template into ``template/``; returns the stage's
    record (None: done already)."""
    if stage_done(store, "paint"):
        log("paint: done already")
        return None
    import tempfile

    template = load_template_shape(store, config)
    grouping = analyse(template, seed=config.seed)
    uv = None
    uv_map = config.shapes().uv_map
    if uv_map:  # the source's own UVs (a .blend graph's UV map), as the user asked
        if template.corner_uv is None:
            raise ValueError(f"the template has no UV map {uv_map!r}")
        uv = source_uv(template, grouping, template.corner_uv, resolution=config.paint.texture_size)
        for note in (n for a in uv.atlases for n in a.notes):
            log(f"paint: {note}")
    tex = paint_with(template, grouping, config.paint, seed=config.seed, up=config.up_axis(), uv=uv, on_view=lambda k, n, st: log(f"paint: view {k + 1}/{n}, {st['texels_updated']} texels"))

    labels = [g.label for g in tex.groups]
    pngs, maps = encoded = encode_textures(tex)  # each image encoded once: the files, the GLB and the record share the bytes
    wheres = [StoreLayout.texture(g, label) for g, label in enumerate(labels)]
    record = Template(
        template,
        grouping,
        tex.uv.corner_uv,
        tex.uv.face_group,
        StoredImages(pngs, wheres),
        labels,
        tex.painted_masks,
        tex.observed_masks,
        StoredMaps(maps, wheres) if any(m is not None for m in maps) else None,
    )
    with tempfile.TemporaryDirectory() as tmp:
        summary = write_textured(tex, tmp, up=config.up_axis(), encoded=encoded)
        textures = {StoreLayout.texture(g, label, kind) for g, label in enumerate(labels) for kind in ("", *MAP_KINDS)}  # the record writes those
        for name in sorted(os.listdir(tmp)):
            if StoreLayout.template_file(name) not in textures:
                store.write_bytes(StoreLayout.template_file(name), (Path(tmp) / name).read_bytes())
    record.save(store)
    log(f"paint: {len(grouping.groups)} groups, unpainted visible pixels {100 * summary['coverage']['share']:.3f}%")
    return {"coverage": summary["coverage"]["share"], "groups": len(grouping.groups), "seconds": round(tex.seconds, 3)}
