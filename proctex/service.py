"""Serving families: load a built family once, answer transfer requests, notice rebuilds.

:class:`FamilyService` holds one family ready for transfer (template assets, networks, mapper, the
painter for new parts); :class:`Catalog` finds the families under a root folder or URI (every
sub-folder with a ``family.json``), keeps their services cached and reloads one when its build
stamp changes (a rebuild or an edit). Both are plain Python: the Ray Serve deployment
(``workers/serve.py``) and any other server wrap them.

Requests are validated here with ``ValueError`` subclasses that a server maps to HTTP codes:
:class:`NotFound` (404), :class:`BadInput` (422) and :class:`TooLarge` (413).
"""

from __future__ import annotations

import json
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .store import FamilyStore


class NotFound(ValueError):
    """An unknown family."""


class BadInput(ValueError):
    """A request that cannot be served as given (bad parameters, unreadable mesh)."""


class TooLarge(ValueError):
    """A request over the size limits."""


@dataclass
class Limits:
    """Request limits: body bytes, mesh vertices and faces."""

    max_bytes: int = 32 * 2**20
    max_vertices: int = 500_000
    max_faces: int = 1_000_000


MESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf")


def build_stamp(store: FamilyStore) -> str:
    """What identifies a family's current build: the stage records and the template's paint record
    (edits append to it). Changes whenever the family is rebuilt or edited."""
    state = store.read_json("family.json") if store.exists("family.json") else {}
    paint = store.read_bytes("template/paint.json") if store.exists("template/paint.json") else b""
    import hashlib

    h = hashlib.sha256(json.dumps(state.get("stages", {}), sort_keys=True).encode())
    h.update(paint)
    return h.hexdigest()[:16]


class FamilyService:
    """One built family, loaded for transfer."""

    def __init__(self, store: FamilyStore, name: str | None = None, limits: Limits | None = None) -> None:
        from .family import _model, load_assets, load_models, stored_config
        from .painters import SurfacePainter
        from .transfer import IdentityMapper, NetworkMapper

        t0 = time.perf_counter()
        self.store = store
        self.name = name or Path(store.base).name
        self.limits = limits or Limits()
        self.stamp = build_stamp(store)
        self.config = stored_config(store)
        self.model = None if self.config.folder else _model(self.config)
        self.assets = load_assets(store)
        self.models = load_models(store)
        self.mapper: Any = NetworkMapper(self.models) if self.models else IdentityMapper()
        self.painter = SurfacePainter(self.config.prompt, seed=self.config.seed)
        self.load_seconds = time.perf_counter() - t0
        self.lock = threading.Lock()  # transfers share the torch models and the painter

    # --------------------------------------------------------------------------------- describe
    def describe(self) -> dict[str, Any]:
        """Parameter specs, groups, prompts and state of the family (JSON-ready)."""
        from .params import infer_space

        if self.model is not None:
            space = self.model.space
        else:
            from .family import samples

            space = infer_space([json.loads(r["params"]) for r in samples(self.store)])
        paint = self.store.read_json("template/paint.json") if self.store.exists("template/paint.json") else {}
        state = self.store.read_json("family.json")
        metrics = self.store.read_json("metrics.json") if self.store.exists("metrics.json") else None
        return {
            "name": self.name,
            "source": {"model": self.config.model, "folder": bool(self.config.folder), "generator": bool(self.config.generator)},
            "inputs": ["params", "mesh"] if self.model is not None else ["mesh"],
            "parameters": [s.to_dict() for s in space.specs],
            "prompt": self.config.prompt,
            "group_prompts": dict(self.config.group_prompts),
            "groups": [{"group": g.group, "label": g.label, "degenerate": g.degenerate, "network": g.group in self.models,
                        "prompt": next((p.get("prompt") for p in paint.get("groups", []) if p.get("group") == g.group), None)}
                       for g in self.assets.groups],
            "stages": {k: v.get("state") for k, v in state.get("stages", {}).items()},
            "stamp": self.stamp,
            "metrics": None if metrics is None else {k: {kk: vv for kk, vv in v.items() if kk != "per_shape"} for k, v in metrics.get("methods", {}).items()},
            "limits": {"max_bytes": self.limits.max_bytes, "max_vertices": self.limits.max_vertices, "max_faces": self.limits.max_faces},
        }

    # --------------------------------------------------------------------------------- transfer
    def shape_from_params(self, params: Any):
        if self.model is None:
            raise BadInput(f"family {self.name!r} comes from a folder of meshes: send a mesh, not parameters")
        if not isinstance(params, dict):
            raise BadInput("params must be a JSON object of parameter values")
        try:
            return self.model.generate(params)
        except ValueError as exc:
            raise BadInput(str(exc)) from exc

    def shape_from_mesh(self, data: bytes, filename: str = "mesh.obj"):
        from .meshio import load_mesh

        if len(data) > self.limits.max_bytes:
            raise TooLarge(f"mesh of {len(data)} bytes is over the limit of {self.limits.max_bytes}")
        suffix = Path(filename or "mesh.obj").suffix.lower() or ".obj"
        if suffix not in MESH_SUFFIXES:
            raise BadInput(f"unsupported mesh type {suffix!r}; send one of {', '.join(MESH_SUFFIXES)}")
        if not data:
            raise BadInput("empty mesh upload")
        with tempfile.TemporaryDirectory() as tmp:
            p = Path(tmp) / f"upload{suffix}"
            p.write_bytes(data)
            try:
                shape, _ = load_mesh(p)
            except Exception as exc:  # ValueError, or a parser crashing on garbage: the client's bad mesh
                text = str(exc).replace(str(p), Path(filename or "mesh").name)[:300]
                raise BadInput(f"cannot read the mesh: {text if isinstance(exc, ValueError) else exc.__class__.__name__ + ': ' + text}") from exc
        if shape.n_vertices > self.limits.max_vertices or shape.n_faces > self.limits.max_faces:
            raise TooLarge(f"mesh has {shape.n_vertices} vertices and {shape.n_faces} faces; limits are "
                           f"{self.limits.max_vertices} and {self.limits.max_faces}")
        return shape

    def transfer(self, shape, seed: int = 0) -> tuple[bytes, dict[str, Any]]:
        """Textured GLB bytes of ``shape`` and a summary (timings, notes)."""
        from .transfer import glb, info, transfer

        t0 = time.perf_counter()
        with self.lock:
            try:
                result = transfer(shape, self.assets, self.mapper, seed=seed, painter=self.painter)
            except ValueError as exc:
                raise BadInput(f"cannot texture this shape: {exc}") from exc
            data = glb(shape, result, self.assets)
        summary = {**info(result), "seconds": round(time.perf_counter() - t0, 4), "faces": shape.n_faces, "vertices": shape.n_vertices, "bytes": len(data)}
        return data, summary


class Catalog:
    """The families under a root folder or URI, served from a cache reloaded on rebuilds.

    ``check_every``: seconds between build-stamp checks of a cached family (0: every request).
    """

    def __init__(self, root: str, limits: Limits | None = None, check_every: float = 2.0) -> None:
        self.root = FamilyStore(root)
        self.limits = limits or Limits()
        self.check_every = check_every
        self._cache: dict[str, tuple[FamilyService, float]] = {}
        self._lock = threading.Lock()
        self.loads = 0

    def names(self) -> list[str]:
        """Families under the root (sub-folders holding a family.json), sorted."""
        try:
            return [n for n in self.root.listdir() if self._is_family(n)]
        except OSError:
            return []

    def _is_family(self, name: str) -> bool:
        return not name.startswith(".") and self.root.exists(f"{name}/family.json")

    def store(self, name: str) -> FamilyStore:
        if not name or "/" in name or name.startswith(".") or not self._is_family(name):
            raise NotFound(f"unknown family {name!r}; families: {', '.join(self.names()) or '(none)'}")
        return FamilyStore(self.root.uri.rstrip("/") + "/" + name)

    def get(self, name: str) -> FamilyService:
        """The service of family ``name`` (loaded or reloaded as needed)."""
        now = time.monotonic()
        with self._lock:
            cached = self._cache.get(name)
            if cached is not None and now - cached[1] < self.check_every:
                return cached[0]
            store = self.store(name)
            if cached is not None and build_stamp(store) == cached[0].stamp:
                self._cache[name] = (cached[0], now)
                return cached[0]
            from .family import stage_done

            if not stage_done(store, "paint"):
                raise NotFound(f"family {name!r} is not built yet (no painted template)")
            service = FamilyService(store, name, self.limits)
            self._cache[name] = (service, now)
            self.loads += 1
            return service
