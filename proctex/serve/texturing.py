"""Texturing a shape with a loaded family (:class:`Texturing`, a mixin of
:class:`proctex.serve.service.FamilyService`): the textured GLB and its summary, with a request's
edits applied to copies of the group textures, and the URIs of the textures and PBR maps that a
linked answer points to instead of carrying them."""

from __future__ import annotations

import time
from typing import Any

from proctex.store.layout import MAP_KINDS
from proctex.transfer.apply import check_transfer_args, info, shape_to_glb
from proctex.transfer.assets import with_images
from proctex.transfer.budget import OverBudget

from .inputs import BadInput, GroupEdit, NotFound


class Texturing:
    """Texturing with the loaded family (``self.assets``, ``self.mapper``, ``self.painter``, the
    snapshot's digests; edits from :class:`proctex.serve.editing.Editing`)."""

    def transfer(self, shape, seed: int = 0, edits: dict[int, GroupEdit] | None = None, budget: Any = None, linked: bool = False) -> tuple[bytes, dict[str, Any]]:
        """Textured GLB bytes of ``shape`` and a summary (timings, notes); see :meth:`textured`."""
        answer, summary = self.textured(shape, seed, edits, budget=budget, linked=linked)
        return answer.data, summary

    def textured(
        self, shape, seed: int = 0, edits: dict[int, GroupEdit] | None = None, bake_size: int | None = None, budget: Any = None, linked: bool = False, link_base: str | None = None
    ) -> tuple[Any, dict[str, Any]]:
        """``shape`` textured by the family (:func:`proctex.transfer.apply.shape_to_glb`, a
        :class:`~proctex.transfer.apply.TexturedGLB`) and a summary (timings, notes).

        ``edits`` ({group index: :class:`GroupEdit`}, see :meth:`parse_edits`) use edited copies of
        those group textures in this GLB only; the family is unchanged. ``bake_size``: give the shape
        its own atlas of that size instead of the template's textures. ``budget``
        (:class:`proctex.transfer.budget.Budget`): past it, or cancelled, the transfer stops with
        :class:`~proctex.transfer.budget.OverBudget`. ``linked``: the GLB refers to the template's
        textures by URI (:meth:`texture_uris`) instead of carrying them, so a client that caches
        them is sent the geometry and UVs only; ``link_base``: the folder those URIs point into
        instead of the texture route (:meth:`texture_uris`)."""
        try:
            check_transfer_args(seed, bake_size)
        except ValueError as exc:
            raise BadInput(str(exc)) from exc
        t0 = time.perf_counter()
        assets = self.assets
        if edits:  # an edited copy of those groups' images, arrays and bytes together (a bake samples the edited colours)
            edited = {g: self.edited_texture(g, edit) for g, edit in edits.items()}
            textures = assets.textures.with_items({g: png for g, (_, png) in edited.items()}, {g: tex for g, (tex, _) in edited.items()})
            maps = assets.pbr
            if maps is not None:
                changed = {g: self.edited_maps(g, edit) for g, edit in edits.items() if edit.changes_maps and assets.pbr_png[g] is not None}
                maps = maps.with_items(changed) if changed else maps
            assets = with_images(assets, textures, maps)  # the UV lookup's tables shared, not made again
        t_edit = time.perf_counter() - t0
        with self.lock:
            try:
                recoloured = {g for g, e in (edits or {}).items() if e.changes_colour}
                uris = self.texture_uris(recoloured, link_base) if linked and not bake_size else None
                m_uris = self.map_uris(edits, link_base) if linked and not bake_size else None
                answer = shape_to_glb(shape, assets, self.mapper, seed=seed, painter=self.painter, up=self.up, bake_size=bake_size, budget=budget, texture_uris=uris, map_uris=m_uris)
            except OverBudget:
                raise
            except ValueError as exc:
                raise BadInput(f"cannot texture this shape: {exc}") from exc
        summary = {**info(answer.result), "seconds": round(time.perf_counter() - t0, 4), "faces": shape.n_faces, "vertices": shape.n_vertices, "bytes": len(answer.data)}
        if edits:
            summary["edits"] = {"groups": sorted(edits), "seconds": round(t_edit, 4)}
        return answer, summary

    def texture_uris(self, edited: Any = (), base: str | None = None) -> list[str | None]:
        """Per template group the URI of its texture, relative to the transfer route's URL
        (``textures/<g>.png?v=<digest>``, see :meth:`texture_png`), or None for the groups in
        ``edited`` (a per-request edit: that texture is this answer's own, so it is embedded).
        ``base``: another folder the textures lie in (files named as :meth:`shared_textures` names
        them, no version query: e.g. ``../textures/`` for files written next to a folder of GLBs)."""
        if base is not None:
            return [None if g in edited else f"{base}{g}.png" for g in range(len(self.texture_digests))]
        look = self._look_query()
        return [None if g in edited else f"textures/{g}.png?v={d[:16]}{look}" for g, d in enumerate(self.texture_digests)]

    def shared_textures(self) -> dict[str, bytes]:
        """``{file name: PNG bytes}`` of every texture and PBR map of the family, as linked answers
        name them without a version (``<g>.png``, ``<g>.orm.png``, ``<g>.normal.png``)."""
        out = {f"{g}.png": png for g, png in enumerate(self.assets.png)}
        for g, maps in enumerate(self.assets.pbr_png or []):
            if maps is not None:
                out[f"{g}.orm.png"], out[f"{g}.normal.png"] = maps.orm, maps.normal
        return out

    def _material_means(self, group: int) -> dict[str, Any]:
        """``{"pbr": bool, "roughness": mean, "metallic": mean}`` of a group's maps over its painted
        texels (what the studio's sliders start at); ``{"pbr": False}`` without maps."""
        import numpy as np

        maps = self.assets.pbr[group] if self.assets.pbr is not None else None
        if maps is None:
            return {"pbr": False}
        orm = maps.orm_uint8()
        mask = self.assets.painted[group] if self.assets.painted is not None and self.assets.painted[group].shape == orm.shape[:2] else np.ones(orm.shape[:2], bool)
        return {"pbr": True, "roughness": round(float(orm[..., 1][mask].mean()) / 255, 3), "metallic": round(float(orm[..., 2][mask].mean()) / 255, 3)}

    def map_uris(self, edits: dict[int, GroupEdit] | None = None, base: str | None = None) -> list[tuple[str, str] | None] | None:
        """Per template group the URIs of its PBR maps (``textures/<g>.orm.png?v=...``,
        ``textures/<g>.normal.png?v=...``; None for a map this answer carries itself: the ORM after a
        re-paint or a roughness / metallic edit, the normal map after a re-paint), or None for a group
        without maps; None when the family has no maps."""
        if self.assets.pbr_png is None:
            return None
        out: list[tuple[str | None, str | None] | None] = []
        for g, d in enumerate(self.map_digests):
            edit = (edits or {}).get(g)
            if d is None:
                out.append(None)
                continue
            orm_uri = f"{base}{g}.orm.png" if base is not None else f"textures/{g}.orm.png?v={d[0][:16]}{self._look_query()}"
            normal_uri = f"{base}{g}.normal.png" if base is not None else f"textures/{g}.normal.png?v={d[1][:16]}{self._look_query()}"
            orm = None if edit is not None and edit.changes_maps else orm_uri
            normal = None if edit is not None and edit.prompt is not None else normal_uri
            out.append((orm, normal))
        return out

    def texture_png(self, group: Any) -> tuple[bytes, str]:
        """``(PNG bytes, sha256 digest)`` of a template group's texture as stored (edits included);
        ``group`` may end in one ``.orm`` or ``.normal`` for one of its PBR maps (``0.normal.orm`` is
        no group)."""
        kind = ""
        text = str(group)
        for k in MAP_KINDS:
            if text.endswith("." + k):
                text, kind = text[: -len(k) - 1], k
                break
        g = self.group_index(text, missing=NotFound)
        if not kind:
            return self.assets.png[g], self.texture_digests[g]
        if self.assets.pbr_png is None or self.assets.pbr_png[g] is None:
            raise NotFound(f"group {g} has no {kind} map (a family painted before PBR maps were made)")
        return getattr(self.assets.pbr_png[g], kind), self.map_digests[g][MAP_KINDS.index(kind)]
