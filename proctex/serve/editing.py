"""Edits of a loaded family's group textures (:class:`Editing`, a mixin of
:class:`proctex.serve.service.FamilyService`): a request's edited copies (re-paint, HSV shift,
roughness and metalness), kept in small LRU caches so that a client dragging a slider costs one
shift per new value; thumbnails; stored edits and their undo (:mod:`proctex.serve.edits`:
versioned, under the family's edit lock)."""

from __future__ import annotations

import io
import threading
from collections import OrderedDict
from typing import Any

from proctex.fileio import encode_png
from proctex.serve.edits import EditConflict, adjust_orm, changed_edit, edit_texture, repaint_maps, undo_edits
from proctex.store.layout import StoreDamaged
from proctex.store.state import Changed
from proctex.texture.pbr import PbrMaps
from proctex.transfer.assets import texture_hw

from .inputs import BadInput, GroupEdit, THUMB_SIZES, parse_edit


_EDIT_LOCK = threading.Lock()  # persisted edits rewrite store files: one at a time per process


class Editing:
    """Edited textures and stored edits of the loaded family (``self.assets``, ``self.store``,
    ``self.look``, ``self.limits``)."""

    def _clear_edit_caches(self) -> None:
        """Empty caches of this look's edited textures and re-paints (each look keeps its own)."""
        self._edited: OrderedDict[tuple[int, GroupEdit], tuple[Any, bytes]] = OrderedDict()
        self._repaints: OrderedDict[tuple[int, str], Any] = OrderedDict()
        self._edit_lock = threading.Lock()
        self.edit_stats = {"hits": 0, "misses": 0, "repaints": 0}

    def edited_texture(self, group: int, edit: GroupEdit) -> tuple[Any, bytes]:
        """``(uint8 (H, W, 3) texture, PNG bytes)`` of template group ``group`` after ``edit``, the same
        texture :func:`proctex.serve.edits.edit_group` would store (an identity edit: the template's own)."""
        import numpy as np

        if not edit.changes_colour:  # identity, or roughness / metalness only
            return self.assets.textures[group], self.assets.png[group]
        key = (group, edit)
        with self._edit_lock:
            hit = self._edited.get(key)
            if hit is not None:
                self._edited.move_to_end(key)
                self.edit_stats["hits"] += 1
                return hit
        base = self.assets.textures[group] if edit.prompt is None else self._repainted(group, edit.prompt)
        tex, _, _ = edit_texture(base, group, self.assets.groups[group].label, edit.hue, edit.saturation, edit.value)
        tex8 = (np.clip(tex, 0, 1) * 255).round().astype(np.uint8)
        out = (tex8, encode_png(tex8))
        with self._edit_lock:
            self.edit_stats["misses"] += 1
            self._edited[key] = out
            while len(self._edited) > self.edit_cache_size:
                self._edited.popitem(last=False)
        return out

    def _repainted(self, group: int, prompt: str):
        """The group's texture re-painted with ``prompt`` (float, before any HSV shift; cached)."""
        key = (group, prompt)
        with self._edit_lock:
            if key in self._repaints:
                self._repaints.move_to_end(key)
                return self._repaints[key]
        ga = self.assets.groups[group]
        tex, _, _ = edit_texture(
            self.assets.textures[group],
            group,
            ga.label,
            prompt=prompt,
            template=self.assets.shape,
            rep_faces=self.assets.grouping.parts[ga.rep].faces,
            rep_corner_uv=ga.corner_uv,
            seed=self.config.seed,
        )
        with self._edit_lock:
            self.edit_stats["repaints"] += 1
            self._repaints[key] = tex
            while len(self._repaints) > max(1, self.edit_cache_size // 4):
                self._repaints.popitem(last=False)
        return tex

    def edited_maps(self, group: int, edit: GroupEdit) -> Any:
        """The group's PBR maps after ``edit`` as PNGs (:class:`proctex.texture.pbr.PbrMaps`), the
        maps :func:`proctex.serve.edits.edit_group` would store: a re-paint makes them again, a
        roughness / metallic edit moves those channels; None when the family has no maps."""
        if self.assets.pbr_png is None or self.assets.pbr_png[group] is None:
            return None
        if not edit.changes_maps:
            return self.assets.pbr_png[group]
        key = ("maps", group, edit.prompt, edit.roughness, edit.metallic)
        with self._edit_lock:
            hit = self._edited.get(key)
            if hit is not None:
                self._edited.move_to_end(key)
                return hit
        if edit.prompt is not None:
            ga = self.assets.groups[group]
            fresh = repaint_maps(edit.prompt, group, ga.label, self.assets.shape, self.assets.grouping.parts[ga.rep].faces, ga.corner_uv, texture_hw(self.assets, group), seed=self.config.seed)
            orm, normal = fresh.orm_uint8(), encode_png(fresh.normal_uint8())
        else:
            orm, normal = self.assets.pbr[group].orm, self.assets.pbr_png[group].normal
        if edit.roughness is not None or edit.metallic is not None:  # means over the painted texels, as the studio shows them
            orm = adjust_orm(orm, edit.roughness, edit.metallic, self.assets.painted[group] if self.assets.painted is not None else None)
        out = PbrMaps(encode_png(orm), normal, self.assets.pbr[group].occlusion)
        with self._edit_lock:
            self._edited[key] = out
            while len(self._edited) > self.edit_cache_size:
                self._edited.popitem(last=False)
        return out

    def thumbnail(self, group: int, edit: GroupEdit, size: Any = 128) -> bytes:
        """PNG of the (edited) group texture scaled to at most ``size`` pixels a side."""
        from PIL import Image

        try:
            n = int(size) if not isinstance(size, bool) else None
        except (TypeError, ValueError):
            n = None
        if n is None or not THUMB_SIZES[0] <= n <= THUMB_SIZES[1]:
            raise BadInput(f"size must be an integer in [{THUMB_SIZES[0]}, {THUMB_SIZES[1]}], got {size!r}")
        tex, png = self.edited_texture(group, edit)
        h, w = tex.shape[:2]
        if max(h, w) <= n:  # never enlarged
            return png
        scale = n / max(h, w)
        img = Image.fromarray(tex).resize((max(1, round(w * scale)), max(1, round(h * scale))), Image.LANCZOS)
        buf = io.BytesIO()
        img.save(buf, format="PNG")
        return buf.getvalue()

    def persist_edit(self, raw: Any, expect_stamp: str | None = None) -> Changed:
        """Store an edit into the family (:func:`proctex.serve.edits.changed_edit`: versioned, under
        the family's edit lock, undoable): ``{"group": index or label, "hue", "saturation", "value",
        "prompt"}``. ``expect_stamp``: the build stamp the edit was made against
        (:class:`~proctex.serve.edits.EditConflict` when the family changed since). Returns the edit
        record and the family's stamp after it, read under the same lock; this service is stale
        afterwards (the catalog reloads the family on its new stamp)."""
        if not isinstance(raw, dict) or "group" not in raw:
            raise BadInput('send {"group": <index or label>, "hue": deg, "saturation": s, "value": v, "prompt": text}')
        g = self.group_index(raw["group"])
        edit = parse_edit(raw, self.limits.max_prompt, extra=("group",))
        if edit.identity:
            raise BadInput("no edit given: send a prompt, a hue, saturation or value change, or a roughness or metallic")
        with _EDIT_LOCK:
            try:
                return changed_edit(
                    self.store,
                    g,
                    expect_stamp=expect_stamp,
                    hue=edit.hue,
                    saturation=edit.saturation,
                    value=edit.value,
                    prompt=edit.prompt,
                    roughness=edit.roughness,
                    metallic=edit.metallic,
                    look=self.look.name,
                )
            except (EditConflict, StoreDamaged):
                raise
            except ValueError as exc:
                raise BadInput(str(exc)) from exc

    def undo_edit(self, expect_stamp: str | None = None, all_edits: bool = False) -> Changed:
        """Undo the family's last stored edit (``all_edits``: every one, back to the painted
        template); returns the undone records and the family's stamp after them, read under the same
        lock. :class:`~proctex.serve.edits.EditConflict` when there is nothing to undo or
        ``expect_stamp`` is stale."""
        with _EDIT_LOCK:
            return undo_edits(self.store, expect_stamp=expect_stamp, look=self.look.name, all_edits=all_edits)
