"""Inputs shared by the benchmarks: a painted built-in template, its assets and shapes, seeded."""

from __future__ import annotations

from functools import lru_cache

from proctex.geometry.parts import analyse
from proctex.models import get_model
from proctex.texture.paint import paint_surface
from proctex.texture.painters import SurfacePainter
from proctex.transfer.assets import prepare_template


@lru_cache(maxsize=4)
def template(model: str = "chair", size: int = 512, prompt: str = "red and white checkered fabric"):
    """(shape, grouping, painted texture, TemplateAssets) of ``model`` at its defaults."""
    shape = get_model(model).generate()
    grouping = analyse(shape)
    tex = paint_surface(shape, grouping, SurfacePainter(prompt), size=size)
    return shape, grouping, tex, prepare_template(shape, grouping, tex.uv.corner_uv, [g.uint8() for g in tex.groups])


def shapes(model: str = "chair", n: int = 4, seed: int = 0):
    m = get_model(model)
    return [m.generate(p) for p in m.space.sample(n, seed=seed)]
