"""The built-in library of part-based procedural models and the model registry."""

from __future__ import annotations

from proctex.geometry.shape import ProceduralModel, check_tessellation
from .registry import REGISTRY as _REGISTRY
from .registry import register

__all__ = ["get_model", "list_models", "register"]


def list_models() -> list[str]:
    """Names of the built-in models, sorted."""
    _load_all()
    return sorted(_REGISTRY)


def get_model(name: str, tessellation: str = "fixed") -> ProceduralModel:
    """A fresh instance of the built-in model ``name`` (``ValueError`` naming the known ones).

    ``tessellation``: ``"fixed"`` (every part keeps its connectivity whatever the parameters) or
    ``"adaptive"`` (segment counts follow the parts' sizes); anything else is a ``ValueError``.
    """
    check_tessellation(tessellation)
    _load_all()
    if name not in _REGISTRY:
        raise ValueError(f"unknown model {name!r}; built-in models are {sorted(_REGISTRY)}")
    return _REGISTRY[name](tessellation=tessellation)


def _load_all() -> None:
    from . import food, furniture, utensils, vessels  # noqa: F401  (registration side effect)
