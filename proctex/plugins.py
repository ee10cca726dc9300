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

ENV = "PROCTEX_PLUGINS"
ENTRY_POINTS = "proctex.plugins"
_LOADED: dict[str, object] = {}
_LOCK = threading.RLock()


def plugin_names(env: str | None = None) -> list[str]:
    """The plugins named in ``env`` (default: ``$PROCTEX_PLUGINS``), in order, without blanks."""
    raw = os.environ.get(ENV, "") if env is None else env
    return [p.strip() for p in raw.split(os.pathsep) if p.strip()]


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
                name = f"proctex_plugin_{path.stem}_{abs(hash(str(path))) % 10**8}"
                loader = importlib.util.spec_from_file_location(name, path)
                if loader is None or loader.loader is None:
                    raise ValueError(f"plugin file {spec!r} is not a Python module")
                module = importlib.util.module_from_spec(loader)
                sys.modules[name] = module
                loader.loader.exec_module(module)
            else:
                module = importlib.import_module(spec)
        except ValueError:
            raise
        except Exception as exc:  # a plugin's own error, named
            raise ValueError(f"plugin {spec!r} failed to load ({type(exc).__name__}: {str(exc)[:300]})") from exc
        _LOADED[spec] = module
        return module


def load_plugins() -> list[str]:
    """Load every plugin of ``$PROCTEX_PLUGINS`` and of the ``proctex.plugins`` entry points not
    loaded yet; returns the plugins loaded so far."""
    from importlib.metadata import entry_points

    with _LOCK:
        for spec in plugin_names():
            load_plugin(spec)
        for ep in entry_points(group=ENTRY_POINTS):
            key = f"entry point {ep.name}"
            if key not in _LOADED:
                try:
                    _LOADED[key] = ep.load()
                except Exception as exc:
                    raise ValueError(f"plugin {key} ({ep.value}) failed to load ({type(exc).__name__}: {str(exc)[:300]})") from exc
        return list(_LOADED)
