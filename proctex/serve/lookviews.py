"""A loaded family's looks (:class:`LookViews`, a mixin of
:class:`proctex.serve.service.FamilyService`): the family textured as another of its looks, made on
first use from that look's files and kept (the shapes, networks and mapper shared), the list of its
looks, a new look painted and stored under the service's limits (:func:`proctex.looks.changed_look`),
and the part-word report and the family's stored words."""

from __future__ import annotations

import copy
from typing import Any

from proctex.looks import LookLimits, LookOverLimit, changed_look, family_parts
from proctex.serve.edits import edit_lock, read_again
from proctex.store.locks import StoreBusy
from proctex.store.looks import UnknownLook, look_paint, look_summary, looks, resolve_look
from proctex.store.partwords import save_part_words
from proctex.store.template import LookImages
from proctex.texture.painters import SurfacePainter

from .edits import EditConflict
from .inputs import BadInput, NotFound, TooLarge


class LookViews:
    """The family's looks (``self.snapshot``, ``self.store``, ``self.config``)."""

    def look_view(self, name: str | None) -> Any:
        """This family textured as its look ``name`` (None, or this service's own look: itself):
        the same shapes, networks and mapper, that look's textures, PBR maps, masks and prompt
        (:func:`proctex.transfer.assets.with_look`), made on first use and kept. :class:`NotFound`
        for a look the family does not have."""
        if name is None or name == self.look.name:
            return self
        with self._views_lock:
            view = self._views.get(name)
            if view is not None:
                return view

            def read() -> tuple[Any, Any, Any]:
                with edit_lock(self.store, shared=True):  # the look's files as one version
                    found = resolve_look(self.store, name)
                    return found, LookImages.read(self.store, found), self.store.read_json(found.PAINT) if self.store.exists(found.PAINT) else {}

            try:
                look, images, paint_record = read_again(read)
            except UnknownLook as exc:
                raise NotFound(str(exc)) from None
            view = copy.copy(self)
            view.snapshot = self.snapshot.as_look(look, look_paint(self.store, look, self.config.paint), images, paint_record)
            view._description = None
            view.painter = SurfacePainter(view.paint.prompt, seed=self.config.seed)
            view._clear_edit_caches()
            view._views, view._views_lock = self._views, self._views_lock  # one table for every look of the family
            self._views[name] = view
            return view

    def looks(self) -> list[dict[str, Any]]:
        """The family's looks (:func:`proctex.store.looks.look_summary`), the build's first."""
        return [look_summary(self.store, lk, self.config.paint) for lk in looks(self.store)]

    def _look_query(self, sep: str = "&") -> str:
        """The query part naming this service's look in a linked texture's URI ("" for the build's)."""
        return "" if self.look.built else f"{sep}look={self.look.name}"

    def add_look(self, name: str, paint: Any, force: bool = False, photos: dict[str, Any] | None = None, budget: Any = None) -> Any:
        """:func:`proctex.looks.changed_look` on this family (its record and the family's version
        after it, read under the lock it was written under) (``photos``: a photo look's photos,
        ``{"glb": bytes}`` for a repainted template, with ``"member": {"glb", "params"}`` for a
        textured member) under the service's look limits (``Limits.look_*``) and ``budget``; a busy
        store or a family at its most looks is a conflict (409), a look over its size 413."""
        lim = self.limits
        limits = LookLimits(seconds=lim.look_seconds, texels=lim.look_texels, bytes=lim.look_bytes, looks=lim.max_looks)
        member = (photos or {}).get("member") if paint.glb else None
        glb = (photos or {}).get("glb") if paint.glb and member is None else None
        try:
            return changed_look(self.store, name, paint, force=force, log=lambda *_: None, timeout=10.0, photos=None if paint.glb else photos, glb=glb, member=member, limits=limits, budget=budget)
        except StoreBusy as exc:
            raise EditConflict(str(exc)) from exc
        except LookOverLimit as exc:
            raise (EditConflict(str(exc)) if exc.kind == "count" else TooLarge(str(exc))) from exc

    def parts(self, prompt: str | None = None, look: str | None = None) -> dict[str, Any]:
        """:func:`proctex.looks.family_parts` of this family (the report, without the mesh): which
        group takes which part word of ``prompt`` (default: ``look``'s prompt)."""
        if prompt is not None and (not isinstance(prompt, str) or len(prompt) > self.limits.max_prompt):
            raise BadInput(f"prompt must be at most {self.limits.max_prompt} characters")
        if look is not None and (not isinstance(look, str) or len(look) > 200):
            raise BadInput("look must be a look's name")
        try:
            return family_parts(self.store, prompt, look)[0]
        except UnknownLook as exc:
            raise NotFound(str(exc)) from None

    def store_parts(self, body: dict[str, Any]) -> dict[str, str]:
        """Store the user's word per group (``{"groups": {"3": "legs"}, "replace": false}``,
        :func:`proctex.store.partwords.save_part_words`); a busy store is a conflict (409)."""
        unknown = set(body) - {"groups", "replace"}
        if unknown:
            raise BadInput(f"unknown fields {sorted(unknown)[:5]}; part words take groups, replace")
        replace = body.get("replace", False)
        if not isinstance(replace, bool):
            raise BadInput("replace must be true or false")
        try:
            return save_part_words(self.store, body.get("groups"), len(self.assets.groups), replace=replace, timeout=10.0)
        except StoreBusy as exc:
            raise EditConflict(str(exc)) from exc
