"""The registry the built-in models add themselves to (:func:`register`); :mod:`proctex.models`
looks them up. Kept apart from the package so the model modules never import the package that
loads them."""

from __future__ import annotations

from proctex.geometry.shape import ProceduralModel

REGISTRY: dict[str, type[ProceduralModel]] = {}


def register(cls: type[ProceduralModel]) -> type[ProceduralModel]:
    """Class decorator adding a built-in model to the registry under ``cls.name``."""
    if not cls.name or cls.name in REGISTRY:
        raise ValueError(f"model name {cls.name!r} is empty or already registered")
    cls.builtin = True
    REGISTRY[cls.name] = cls
    return cls
