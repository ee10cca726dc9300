"""Correspondence methods: the one registry of what maps a shape's parts onto the template's group
representatives. The CLI (``proctex transfer --mapper``, ``proctex eval --methods``, ``proctex
correspond --method``), the evaluation and the service all read it, so a method added here (or by a
plugin, :mod:`proctex.plugins`) is offered everywhere at once.

A :class:`Method` is a name, a one-line summary and ``make``, which builds its
:class:`proctex.transfer.mappers.Mapper` from a :class:`MethodContext` (the template assets, the
family's networks and its pair settings). Adding one is one file::

    from proctex.transfer.methods import Method, register
    from proctex.transfer.mappers import IdentityMapper

    register(Method("mine", lambda ctx: IdentityMapper(), "what it does"))

and ``PROCTEX_PLUGINS=path/to/that_file.py`` (or a ``proctex.plugins`` entry point).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any, Callable

from proctex.plugins import Registry
from proctex.transfer.assets import TemplateAssets
from proctex.transfer.mappers import IdentityMapper, Mapper, NetworkMapper, SolverMapper

NETWORKS = ("none", "optional", "required")
NAME = re.compile(r"^[a-z][a-z0-9_]{0,39}$")


@dataclass(frozen=True)
class MethodContext:
    """What a method builds its mapper from: the template ready for transfer, the family's networks
    (group -> ProcCorrNet; empty when not trained or not loaded), the number of surface points a
    solver samples per part and the family's cage settings (as the build solves its pairs), and the
    networks' autocast (:class:`proctex.transfer.mappers.NetworkMapper`)."""

    assets: TemplateAssets
    models: dict[int, Any] = field(default_factory=dict)
    corr_points: int = 2000
    cage: Any = None
    autocast: str = "auto"


@dataclass(frozen=True)
class Method:
    """A correspondence method.

    Attributes:
        name: what users type (lower case, digits and ``_``; at most 40 characters).
        make: ``MethodContext -> Mapper``.
        summary: one line for help texts.
        networks: whether it uses the family's trained networks: "none", "optional" (where there
            are any) or "required" (a family without them is a ``ValueError``).
        shortcut: parts with the template representative's exact connectivity take its UVs
            directly (ProcTex's run-time path); the evaluation's other methods map every part.
        evaluate: compared by ``proctex eval`` by default.
        solver: a pairwise solver of :mod:`proctex.correspond.dense` (``proctex correspond --method``).
        aliases: other names accepted for it.
    """

    name: str
    make: Callable[[MethodContext], Mapper]
    summary: str = ""
    networks: str = "none"
    shortcut: bool = False
    evaluate: bool = True
    solver: bool = False
    aliases: tuple[str, ...] = ()

    def check(self) -> "Method":
        for n in (self.name, *self.aliases):
            if not isinstance(n, str) or not NAME.match(n):
                raise ValueError(f"a method name must match {NAME.pattern}, got {str(n)[:60]!r}")
        if not callable(self.make):
            raise ValueError(f"method {self.name!r}: make must be callable")
        if self.networks not in NETWORKS:
            raise ValueError(f"method {self.name!r}: networks must be one of {', '.join(NETWORKS)}, got {self.networks!r}")
        return self


_METHODS: Registry[Method] = Registry("method", lambda name, known: f"unknown method {name!r}; known: {', '.join(known)}")


def register(method: Method, replace: bool = False) -> Method:
    """Add ``method`` to the registry (``replace``: over one of the same name); a name or alias taken
    by another method is a ``ValueError``. Returns it."""
    return _METHODS.add(method.check().name, method, method.aliases, replace)


def unregister(name: str) -> None:
    """Remove method ``name`` and its aliases (a test's, or a plugin's being replaced)."""
    _METHODS.remove(name)


def methods() -> list[Method]:
    """Every registered method (plugins loaded), in registration order."""
    return _METHODS.entries()


def method_names(aliases: bool = False, evaluate: bool | None = None, solver: bool | None = None) -> tuple[str, ...]:
    """The names of the registered methods (with their ``aliases``), optionally only those that
    ``evaluate`` by default or are pairwise ``solver``s."""
    out = []
    for m in methods():
        if (evaluate is None or m.evaluate == evaluate) and (solver is None or m.solver == solver):
            out += [m.name, *(m.aliases if aliases else ())]
    return tuple(out)


def get_method(name: str) -> Method:
    """The method called ``name`` (or one of its aliases); ``ValueError`` listing the known names."""
    return _METHODS.get(name)


def method_help() -> str:
    """``name (aliases): summary`` of every method, for help texts."""
    return "; ".join(f"{m.name}{' (' + ', '.join(m.aliases) + ')' if m.aliases else ''}: {m.summary}" for m in methods())


def make_mapper(name: str, assets: TemplateAssets, models: dict[int, Any] | None = None, corr_points: int = 2000, cage: Any = None, autocast: str = "auto") -> Mapper:
    """The mapper of method ``name`` (:func:`get_method`) for ``assets``: the one place a mapper is
    chosen by name (the CLI, the service and the evaluation use it). ``models``: the family's
    networks; a method that requires them and gets none is a ``ValueError``."""
    method = get_method(name)
    if method.networks == "required" and not models:
        raise ValueError("no trained models (run the train stage)")
    return method.make(MethodContext(assets, dict(models or {}), int(corr_points), cage, autocast))


# The built-in methods, in the order ``proctex eval`` compares them.
register(
    Method(
        "auto",
        lambda c: NetworkMapper(c.models, autocast=c.autocast) if c.models else IdentityMapper(),
        "the family's networks where the build chose them, else the identity (the default)",
        networks="optional",
        evaluate=False,
    )
)
register(
    Method(
        "corrnet",
        lambda c: NetworkMapper(c.models, autocast=c.autocast),
        "the run-time path: the networks (or box map) the build chose per group; parts with the template's connectivity take its UVs",
        networks="required",
        shortcut=True,
        aliases=("net",),
    )
)
register(Method("corrnet_all", lambda c: NetworkMapper(c.models, autocast=c.autocast, follow=False), "the network on every part of every group it has", networks="required"))
for _name, _summary in (
    ("cage", "the cage solver per part at transfer time, as the build solves its pairs (seconds per part)"),
    ("nearest", "similarity alignment, then nearest points"),
    ("cpd", "coherent point drift per part"),
):
    register(Method(_name, lambda c, _n=_name: SolverMapper(c.assets, _n, n_points=c.corr_points, cage=c.cage), _summary, solver=True))
register(Method("identity", lambda c: IdentityMapper(), "the normalised frames taken to coincide (the baseline)"))
