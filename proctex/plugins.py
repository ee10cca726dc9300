"""Extensions from outside the package: a plugin is a Python module (or a ``.py`` file) that, when
imported, registers what it adds (a correspondence method with
:func:`proctex.transfer.methods.register`, a painter, a shape source). The registries load the
plugins named in ``PROCTEX_PLUGINS`` (module names or file paths, separated by ``os.pathsep``) and
the ``proctex.plugins`` entry points of installed packages, once per process, before their first
lookup (:func:`load_plugins`)."""

from __future__ import annotations

import importlib
import importlib.util
import os
import sys
import threading
from pathlib import Path
from typing import Any, Callable, Generic, TypeVar

T = TypeVar("T")

ENV = "PROCTEX_PLUGINS"
ENTRY_POINTS = "proctex.plugins"
_LOADED: dict[str, object] = {}
_LOCK = threading.RLock()


def plugin_names(env: str | None = None) -> list[str]:
    """The plugins named in ``env`` (default: ``$PROCTEX_PLUGINS``), in order, without blanks."""
    raw = os.environ.get(ENV, "") if env is None else env
    return [p.strip() for p in raw.split(os.pathsep) if p.strip()]


def import_file(path: Path, prefix: str) -> Any:
    """Import the Python file ``path`` as a module of its own (named ``<prefix>_<stem>_<hash>``,
    registered in ``sys.modules``); ``ValueError`` when it is not a Python module."""
    name = f"{prefix}_{path.stem}_{abs(hash(str(path.resolve()))) % 10**8}"
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise ValueError(f"cannot import {path}: not a Python module")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def load_plugin(spec: str) -> object:
    """Import plugin ``spec`` (a module name, or a path to a ``.py`` file) once; ``ValueError`` with
    the cause when it cannot be imported."""
    with _LOCK:
        if spec in _LOADED:
            return _LOADED[spec]
        try:
            if spec.endswith(".py") or os.sep in spec:
                path = Path(spec).resolve()
                if not path.is_file():
                    raise ValueError(f"plugin file {spec!r} not found")
                module = import_file(path, "proctex_plugin")
            else:
                module = importlib.import_module(spec)
        except ValueError:
            raise
        except Exception as exc:  # a plugin's own error, named
            raise ValueError(f"plugin {spec!r} failed to load ({type(exc).__name__}: {str(exc)[:300]})") from exc
        _LOADED[spec] = module
        return module


_SCANNED: set[tuple[str, ...]] = set()  # the import paths whose installed packages' entry points were read


def load_plugins() -> list[str]:
    """Load every plugin of ``$PROCTEX_PLUGINS`` and of the ``proctex.plugins`` entry points not
    loaded yet; returns the plugins loaded so far. The installed packages' entry points are read
    once per import path (``sys.path``: reading them takes about 10 ms, and every registry lookup
    comes here); a package installed into a running process is found once the path changes."""
    import sys
    from importlib.metadata import entry_points

    with _LOCK:
        for spec in plugin_names():
            load_plugin(spec)
        path = tuple(sys.path)
        if path in _SCANNED:
            return list(_LOADED)
        for ep in entry_points(group=ENTRY_POINTS):
            key = f"entry point {ep.name}"
            if key not in _LOADED:
                try:
                    _LOADED[key] = ep.load()
                except Exception as exc:
                    raise ValueError(f"plugin {key} ({ep.value}) failed to load ({type(exc).__name__}: {str(exc)[:300]})") from exc
        _SCANNED.add(path)
        return list(_LOADED)


class Registry(Generic[T]):
    """The entries of one extension axis by name (and alias), in registration order, the plugins
    loaded before every lookup (:func:`load_plugins`); thread-safe. ``what`` names an entry in
    messages; ``unknown(name, known)`` is the message of a failed lookup."""

    def __init__(self, what: str, unknown: Callable[[str, tuple[str, ...]], str]) -> None:
        self.what, self.unknown = what, unknown
        self._entries: dict[str, T] = {}
        self._aliases: dict[str, str] = {}
        self._lock = threading.RLock()

    def add(self, name: str, entry: T, aliases: tuple[str, ...] = (), replace: bool = False) -> T:
        """Register ``entry`` as ``name`` (and ``aliases``); a name taken by another entry (or by
        this one, without ``replace``) is a ``ValueError``."""
        with self._lock:
            taken = {n: self._aliases.get(n, n) for n in (name, *aliases) if n in self._entries or n in self._aliases}
            clash = {n: owner for n, owner in taken.items() if owner != name or not replace}
            if clash:
                raise ValueError(f"{self.what} names already taken: {', '.join(f'{n} (by {o})' for n, o in clash.items())}")
            self._entries[name] = entry
            self._aliases.update({a: name for a in aliases})
        return entry

    def remove(self, name: str) -> None:
        """Remove ``name`` and its aliases."""
        with self._lock:
            self._entries.pop(name, None)
            for a in [a for a, owner in self._aliases.items() if owner == name]:
                del self._aliases[a]

    def entries(self) -> list[T]:
        load_plugins()
        with self._lock:
            return list(self._entries.values())

    def names(self, aliases: bool = False) -> tuple[str, ...]:
        load_plugins()
        with self._lock:
            return tuple(self._entries) + (tuple(self._aliases) if aliases else ())

    def get(self, name: Any) -> T:
        """The entry called ``name`` (or an alias of it); ``ValueError`` (:attr:`unknown`)."""
        load_plugins()
        with self._lock:
            key = self._aliases.get(name, name) if isinstance(name, str) else None
            if key in self._entries:
                return self._entries[key]
        raise ValueError(self.unknown(str(name)[:60], self.names(aliases=True)))
