"""Painters: the one registry of what paints a template, and the paint settings that travel whole
(:class:`PaintConfig`, the ``[paint]`` section of a build config, as ``CageConfig`` is the
``[cage]`` one).

A :class:`Painter` entry is a name, whether it paints through the multi-view loop (``views``) or
the surface pass, ``make`` (a :class:`PainterContext` -> the painter object) and ``check`` (what it
needs of the settings). Adding one is one file::

    from proctex.texture.painting import Painter, register_painter
    register_painter(Painter("mine", make=lambda ctx: MyViewPainter(...), views=True, summary="..."))

and ``PROCTEX_PLUGINS=path/to/that_file.py`` (:mod:`proctex.plugins`).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

from proctex.geometry.parts import Grouping
from proctex.params import check_integer
from proctex.plugins import Registry

NAME = re.compile(r"^[a-z][a-z0-9_]{0,39}$")
FILLS = ("patchmatch", "surface")


@dataclass(frozen=True)
class PainterContext:
    """What a painter is made from: the template's grouping, the prompt and the per-group prompts
    (group index -> text), the seed and the paint settings."""

    grouping: Grouping
    prompt: str
    prompts: Mapping[int, str]
    seed: int
    settings: "PaintConfig"


@dataclass(frozen=True)
class Painter:
    """A template painter.

    Attributes:
        name: what users type (``[paint] painter``, ``--painter``).
        make: ``PainterContext -> painter``: a surface painter (``views`` False: colours at 3D points,
            :class:`proctex.texture.painters.SurfacePainter`'s interface) or a view painter
            (:class:`proctex.texture.painters.base.ViewPainter`, run by the multi-view loop).
        views: paints through the multi-view loop (else the surface pass).
        summary: one line for help texts.
        check: ``check(settings)`` raises ``ValueError`` for settings it cannot work with.
    """

    name: str
    make: Callable[[PainterContext], Any]
    views: bool = False
    summary: str = ""
    check: Callable[["PaintConfig"], None] | None = None


_PAINTERS: Registry[Painter] = Registry("painter", lambda name, known: f"painter must be one of {', '.join(known)}, got {name!r}")


def register_painter(painter: Painter, replace: bool = False) -> Painter:
    """Add ``painter`` to the registry (``replace``: over one of the same name); returns it."""
    if not isinstance(painter.name, str) or not NAME.match(painter.name):
        raise ValueError(f"a painter name must match {NAME.pattern}, got {str(painter.name)[:60]!r}")
    if not callable(painter.make):
        raise ValueError(f"painter {painter.name!r}: make must be callable")
    return _PAINTERS.add(painter.name, painter, replace=replace)


def unregister_painter(name: str) -> None:
    _PAINTERS.remove(name)


def painter_names() -> tuple[str, ...]:
    """The registered painters (plugins loaded), in registration order."""
    return _PAINTERS.names()


def get_painter(name: str) -> Painter:
    """The painter called ``name``; ``ValueError`` listing the known ones."""
    return _PAINTERS.get(name)


def painter_help() -> str:
    return "; ".join(f"{p.name}: {p.summary}" for p in _PAINTERS.entries())


#: The bounds of what a look or a build is told to paint, the same on the command line and over
#: HTTP (the service's ``Limits.max_prompt`` defaults to it): characters of a prompt and of each
#: group prompt, group prompts, and characters of a group prompt's key (a group number, label or
#: part word).
MAX_PROMPT = 200
MAX_GROUP_PROMPTS = 256
MAX_GROUP_KEY = 64


@dataclass
class PaintConfig:
    """How the template is painted.

    Attributes:
        prompt, group_prompts: what to paint (group prompts keyed by group label, index or part word).
        part_words: the user's word per group (``{"3": "legs"}``,
            :func:`proctex.texture.painters.partwords.check_assignment`): the prompt's clause naming
            that word paints that group, whatever the geometry or the labels say.
        texture_size, painter: template texturing, one of the registered painters
            (:func:`painter_names`): "surface" (the solid surface painter), "views" (the multi-view
            loop with the offline view painter) or "diffusion" (the multi-view loop with a local
            diffusers model in ``model_dir``).
        views, view_size, paint_hidden, fill: the multi-view loop (cameras on the orbit, their size,
            whether parts hidden from the orbit get views of their own, and how unseen texels are
            filled: "patchmatch" or "surface"). Texels no view saw stay out of the template's
            "already painted" mask, so transfer can detect dis-occlusion.
        model_dir, device, steps: the diffusion painter.
        occlusion: bake ambient occlusion into the PBR maps (the ORM's R channel).
        images: photos painted on groups (a look from photos, :mod:`proctex.texture.exemplar`): key
            (a group number, label or part word, or ``"*"``: the groups nothing else names) ->
            ``{"file", "scale", "rotate", "normal", "roughness", ...}`` (:func:`proctex.texture.exemplar.check_images`);
            such a look paints with the surface painter.
        glb: a look read from a repainted template GLB (:mod:`proctex.texture.fromglb`): its file's
            ``name``, ``sha256`` and match counts, for the record.
    """

    prompt: str = "oak"
    group_prompts: dict[str, str] = field(default_factory=dict)
    part_words: dict[str, str] = field(default_factory=dict)
    painter: str = "surface"
    texture_size: int = 512
    views: int = 11
    view_size: int = 512
    paint_hidden: bool = True
    fill: str = "patchmatch"
    model_dir: str | None = None
    device: str = "cpu"
    steps: int = 20
    occlusion: bool = False
    images: dict[str, dict[str, Any]] = field(default_factory=dict)
    glb: dict[str, Any] = field(default_factory=dict)

    def validate(self) -> "PaintConfig":
        if not isinstance(self.prompt, str):
            raise ValueError("prompt must be a string")
        if len(self.prompt) > MAX_PROMPT:
            raise ValueError(f"the prompt has {len(self.prompt)} characters (at most {MAX_PROMPT})")
        if not isinstance(self.group_prompts, dict) or not all(isinstance(v, str) for v in self.group_prompts.values()):
            raise ValueError("group_prompts must be an object of prompts {group label or index: prompt}")
        if len(self.group_prompts) > MAX_GROUP_PROMPTS or not all(len(str(k)) <= MAX_GROUP_KEY and len(v) <= MAX_PROMPT for k, v in self.group_prompts.items()):
            raise ValueError(f"group_prompts takes at most {MAX_GROUP_PROMPTS} prompts of at most {MAX_PROMPT} characters, keyed by names of at most {MAX_GROUP_KEY}")
        from proctex.texture.painters.partwords import check_assignment

        self.part_words = {str(k): v for k, v in check_assignment(self.part_words).items()}
        check_integer("texture_size", self.texture_size, 16, 8192)
        check_integer("views", self.views, 3, 256)
        check_integer("view_size", self.view_size, 16, 4096)
        check_integer("steps", self.steps, 1, 1000)
        painter = get_painter(self.painter)
        if self.fill not in FILLS:
            raise ValueError(f"fill must be patchmatch or surface, got {self.fill!r}")
        if not isinstance(self.occlusion, bool):
            raise ValueError(f"occlusion must be true or false, got {self.occlusion!r}")
        if painter.check is not None:
            painter.check(self)
        if self.images:
            from proctex.texture.exemplar import check_images

            self.images = check_images(self.images)
            if painter.views:
                raise ValueError(f"a look from photos paints with the surface painter, not {self.painter!r}")
        elif self.images != {}:
            raise ValueError("images must be an object {part: photo}")
        if not isinstance(self.glb, dict) or len(self.glb) > 8 or not all(isinstance(k, str) and isinstance(v, (str, int, float, bool)) and len(str(v)) <= 400 for k, v in self.glb.items()):
            raise ValueError("glb must be a short object (the repainted template GLB's name, checksum and match counts)")
        if self.glb and self.images:
            raise ValueError("a look comes from a repainted template GLB or from photos, not both")
        return self


def make_painter(
    name: str,
    grouping: Grouping,
    prompt: str,
    prompts: Mapping[int, str] | None = None,
    seed: int = 0,
    model_dir: str | None = None,
    device: str = "cpu",
    steps: int = 20,
    settings: PaintConfig | None = None,
) -> Any:
    """The painter ``name`` of the registry (:func:`get_painter`), the one place painters are made:
    "surface" (a :class:`~proctex.texture.painters.SurfacePainter`: colours at 3D points, ``prompts``
    per group index), "views" (a :class:`proctex.texture.paint.SolidViewPainter` over it, for the
    multi-view loop) or "diffusion" (a local diffusers model in ``model_dir``). ``settings``: the
    paint settings (else made of ``model_dir``, ``device`` and ``steps``). ``ValueError`` for another name."""
    painter = get_painter(name)
    settings = settings if settings is not None else PaintConfig(prompt=prompt, painter=name, model_dir=model_dir, device=device, steps=steps)
    return painter.make(PainterContext(grouping, prompt, dict(prompts or {}), seed, settings))


def _surface(ctx: PainterContext) -> Any:
    from proctex.texture.painters import SurfacePainter

    return SurfacePainter(ctx.prompt, {str(k): v for k, v in ctx.prompts.items()}, seed=ctx.seed)


def _views(ctx: PainterContext) -> Any:
    from proctex.texture.paint import SolidViewPainter

    return SolidViewPainter(_surface(ctx), ctx.grouping)


def _diffusion(ctx: PainterContext) -> Any:
    from proctex.texture.painters.diffusion import DiffusionViewPainter

    return DiffusionViewPainter(ctx.settings.model_dir, device=ctx.settings.device, steps=ctx.settings.steps)


def _needs_model_dir(settings: PaintConfig) -> None:
    if not (settings.model_dir and os.path.isdir(settings.model_dir)):
        raise ValueError(f"painter 'diffusion' needs model_dir, a local diffusers model folder (got {settings.model_dir!r})")


register_painter(Painter("surface", _surface, summary="the solid surface painter (colours at 3D points; the default)"))
register_painter(Painter("views", _views, views=True, summary="the multi-view loop with the offline view painter"))
register_painter(Painter("diffusion", _diffusion, views=True, summary="the multi-view loop with a local diffusers model (model_dir)", check=_needs_model_dir))
