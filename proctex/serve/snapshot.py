"""A loaded family as one immutable value (:class:`Snapshot`): what a service read of one version of
the family, under one shared edit lock, and the digests of exactly the textures it holds."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, replace
from typing import Any

from proctex.params import ParamSpace
from proctex.sources.registry import SourceKind, source_kind
from proctex.store.config import BuildConfig
from proctex.store.family import Family
from proctex.store.layout import LookLayout
from proctex.store.looks import look_paint, resolve_look
from proctex.texture.painting import PaintConfig
from proctex.transfer.assets import TemplateAssets, template_assets, with_look


def texture_digests(assets: TemplateAssets) -> tuple[tuple[str, ...], tuple[tuple[str, str] | None, ...]]:
    """The sha256 of every texture PNG of ``assets`` and of each group's PBR maps (ORM, normal; None
    for a group without maps): the ETags and versions of linked answers."""
    tex = tuple(hashlib.sha256(png).hexdigest() for png in assets.png)
    maps = tuple(None if m is None else (hashlib.sha256(m.orm).hexdigest(), hashlib.sha256(m.normal).hexdigest()) for m in (assets.pbr_png or [None] * len(assets.png)))
    return tex, maps


@dataclass(frozen=True)
class Snapshot:
    """One version of a family as a service serves it, textured as one look.

    Attributes:
        family: the records (:class:`proctex.store.family.Family`): state, version, config.
        source_kind: the kind of its shape source (the source itself is opened on first use).
        up: the up axis GLBs stand the shape on.
        look, paint: the look served and its paint settings (its prompts paint new parts).
        assets: the template ready for transfer (frozen: its arrays and PNG bytes are one object).
        models: {group: ProcCorrNet} where the method uses networks.
        paint_record, metrics_record, look_names, space: what ``describe()`` says, of this version.
        texture_digests, map_digests: of exactly ``assets``' PNGs (:func:`texture_digests`).
    """

    family: Family
    source_kind: SourceKind
    up: str
    look: LookLayout
    paint: PaintConfig
    assets: TemplateAssets
    models: dict[int, Any]
    paint_record: dict[str, Any]
    metrics_record: dict[str, Any] | None
    look_names: tuple[str, ...]
    space: ParamSpace
    texture_digests: tuple[str, ...]
    map_digests: tuple[tuple[str, str] | None, ...]

    @property
    def config(self) -> BuildConfig:
        return self.family.config

    @property
    def stamp(self) -> str:
        """The family's version (``family.version``)."""
        return self.family.version

    def as_look(self, look: LookLayout, paint: PaintConfig, images: Any, paint_record: dict[str, Any]) -> "Snapshot":
        """The same version textured as another ``look`` (its images read by
        :meth:`proctex.store.template.LookImages.read`): shapes, networks and space shared."""
        assets = with_look(self.assets, images)
        tex, maps = texture_digests(assets)
        return replace(self, look=look, paint=paint, assets=assets, paint_record=paint_record, texture_digests=tex, map_digests=maps)


def read_snapshot(family: Family, look: str | None = None, networks: bool = True, device: str = "cpu") -> Snapshot:
    """A :class:`Snapshot` of ``family`` (opened under the caller's shared edit lock) as its ``look``
    (None: the build's); ``networks``: load the group networks onto ``device``."""
    store, config = family.store, family.config
    layout = resolve_look(store, look)
    assets = template_assets(family.template(layout))
    tex, maps = texture_digests(assets)
    return Snapshot(
        family=family,
        source_kind=source_kind(config.source),
        up=config.up_axis(),
        look=layout,
        paint=look_paint(store, layout, config.paint),
        assets=assets,
        models=family.networks(device) if networks else {},
        paint_record=store.read_json(layout.PAINT) if store.exists(layout.PAINT) else {},
        metrics_record=family.metrics,
        look_names=tuple(lk.name for lk in family.looks),
        space=family.space,
        texture_digests=tex,
        map_digests=maps,
    )
