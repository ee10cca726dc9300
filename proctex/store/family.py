"""A built family's records behind one handle (:class:`Family`): ``Family.open(uri)`` reads
``family.json`` once and gives the family's one version value; the config, samples, template,
networks and looks are typed records, each read at most once, from the same state. No record load
makes a shape or starts a program: the template shape is read as the template stage recorded it.

    family = Family.open("runs/sofa")
    family.version            # what every cache and conditional change keys on
    family.config.paint.prompt
    template = family.template()          # textured as the build's look
    nets = family.networks("cpu")
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cached_property
from typing import Any

from proctex.geometry.shape import Shape
from proctex.params import ParamSpace, infer_space
from proctex.sources.registry import source_kind
from proctex.store.config import BuildConfig
from proctex.store.layout import FamilyStore, LookLayout, StoreDamaged, StoreLayout
from proctex.store.looks import looks, resolve_look
from proctex.store.networks import load_models
from proctex.store.samples import samples
from proctex.store.state import FamilyState, build_stamp
from proctex.store.template import Template, load_template_shape


@dataclass(frozen=True)
class Family:
    """One family's records as of one version.

    Attributes:
        store: where it lives.
        state: ``family.json``, read once (:class:`FamilyState`).
        version: the family's version (:func:`proctex.store.state.build_stamp` of ``state``): it changes
            whenever the family is rebuilt, edited, or a look is added or removed.
    """

    store: FamilyStore
    state: FamilyState
    version: str

    @classmethod
    def open(cls, where: str | FamilyStore, state: FamilyState | None = None) -> "Family":
        """The family at ``where`` (a path, a URI or a store); ``state``: its ``family.json`` when
        the caller has just read it. A damaged ``family.json`` is a ``ValueError`` naming it; a folder
        with none opens as a family that is not built (no stage done; :attr:`config` raises)."""
        store = where if isinstance(where, FamilyStore) else FamilyStore(where)
        state = state if state is not None else FamilyState.load(store)
        return cls(store, state, build_stamp(store, state))

    @cached_property
    def config(self) -> BuildConfig:
        """The config it was built with (devices read as "cpu")."""
        return self.state.build_config(self.store.uri)

    def done(self, stage: str) -> bool:
        return self.state.done(stage)

    @cached_property
    def samples(self) -> list[dict[str, Any]]:
        """The rows of ``samples.parquet`` (id, split, params JSON, mesh path)."""
        return samples(self.store)

    @cached_property
    def space(self) -> ParamSpace:
        """Its parameter space: a procedural model's as the sample stage recorded it; a folder's
        inferred from its samples. A family built before the record opens its model for it, unless
        making a shape starts another program (Blender): then its space is inferred from its samples."""
        recorded = self.state.stage("sample").get("space")
        if recorded is not None:
            try:
                return ParamSpace.from_list(recorded)
            except (TypeError, ValueError, KeyError, AttributeError) as exc:
                raise StoreDamaged(f"{self.store.uri}: family.json: the sample stage's parameter space is damaged ({str(exc)[:200]})") from exc
        kind = source_kind(self.config.source)
        if kind.regenerates and not kind.starts_program:
            return self.config.procedural_model().space
        return infer_space([json.loads(r["params"]) for r in self.samples])

    @cached_property
    def template_shape(self) -> Shape:
        """The template shape as recorded (:func:`proctex.store.template.load_template_shape`)."""
        return load_template_shape(self.store, self.config, self.state)

    def template(self, look: LookLayout | str | None = None) -> Template:
        """The textured template as ``look`` (a layout or a name; None: the build's look)."""
        layout = look if isinstance(look, LookLayout) else resolve_look(self.store, look)
        return Template.load(self.store, self.template_shape, seed=self.config.seed, look=layout)

    def networks(self, device: str = "cpu") -> dict[int, Any]:
        """{group: ProcCorrNet} of the trained groups, checked against the train stage's record."""
        return load_models(self.store, device, self.state)

    @cached_property
    def looks(self) -> list[LookLayout]:
        """Its looks, the build's first."""
        return looks(self.store)

    @cached_property
    def metrics(self) -> dict[str, Any] | None:
        """The evaluate stage's ``metrics.json`` (None before it ran)."""
        return self.store.read_json(StoreLayout.METRICS) if self.store.exists(StoreLayout.METRICS) else None
