"""Where shapes come from: built-in models, folders of samples, a user's Python generator.

- :class:`FolderSource` reads the layout of ``shared/data/procedural_sofa``: mesh files plus a JSON
  file of parameters with the same stem, either flat or in ``train/`` and ``inference/`` (or
  ``test/``) sub-folders.
- :class:`PythonGenerator` wraps a user's function named in a config file (JSON or TOML)::

      [generator]
      name = "my_family"
      module = "my_gen.py"        # a file (relative to the config) or an importable module
      function = "generate"       # params dict -> Shape | (vertices, faces) | trimesh.Trimesh | dict
      params = [ { name = "width", kind = "continuous", low = 1.0, high = 2.0, default = 1.5 } ]

  ``params`` may instead come from a ``PARAMS`` list in the module.
- :func:`resolve_shape` turns a command-line shape argument into a :class:`Shape`: a mesh file, a
  built-in model name (defaults), or ``MODEL:{"param": value, ...}``.
"""

from __future__ import annotations

import importlib
import importlib.util
import json
import os
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from proctex.geometry.meshio import FORMATS, load_mesh, read_params
from proctex.geometry.shape import ProceduralModel, Shape
from proctex.models import get_model, list_models
from proctex.params import ParamSpace, infer_space, select_template
from proctex.plugins import import_file

SPLIT_ALIASES = {"train": "train", "inference": "test", "test": "test"}


@dataclass(frozen=True)
class FolderSample:
    """One sample of a folder: ``id`` (e.g. ``"train/0"``), ``split``, mesh and parameter paths."""

    id: str
    split: str
    mesh_path: str
    params_path: str | None

    @property
    def store_id(self) -> str:
        """The sample's id in a family store (``train_3`` for ``train/3``)."""
        return self.id.replace("/", "_")


class FolderSource:
    """A folder of samples (mesh files + JSON parameters), flat or split into train/inference."""

    def __init__(self, root: str | os.PathLike) -> None:
        self.root = Path(root)
        if not self.root.is_dir():
            raise ValueError(f"{root}: not a folder")
        self.samples = self._scan()
        if not self.samples:
            raise ValueError(f"{root}: no mesh files ({', '.join(sorted(FORMATS))}) found")
        self._params = [read_params(s.params_path) if s.params_path else {} for s in self.samples]
        self.space: ParamSpace = infer_space(self._params) if all(self._params) else ParamSpace(())

    def _scan(self) -> list[FolderSample]:
        subdirs = [d for d in sorted(self.root.iterdir()) if d.is_dir() and d.name in SPLIT_ALIASES]
        layout = [(d, SPLIT_ALIASES[d.name], d.name + "/") for d in subdirs] or [(self.root, "train", "")]
        out: list[FolderSample] = []
        for folder, split, prefix in layout:
            meshes = [p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in FORMATS]
            # Natural order: numeric stems by value, then the rest by name.
            meshes.sort(key=lambda p: (0, int(p.stem), "") if p.stem.isdigit() else (1, 0, p.stem))
            for m in meshes:
                pj = m.with_suffix(".json")
                out.append(FolderSample(prefix + m.stem, split, str(m), str(pj) if pj.is_file() else None))
        return out

    def __len__(self) -> int:
        return len(self.samples)

    def params(self, i: int) -> dict[str, Any]:
        return dict(self._params[i])

    def indices(self, split: str | None = None) -> list[int]:
        """Sample indices, optionally of one split (``"train"`` or ``"test"``)."""
        if split is not None and split not in ("train", "test"):
            raise ValueError(f"split must be 'train' or 'test', got {split!r}")
        return [i for i, s in enumerate(self.samples) if split is None or s.split == split]

    def load(self, i: int) -> Shape:
        shape, _ = load_mesh(self.samples[i].mesh_path)
        shape.params = self.params(i)
        return shape

    def template_index(self) -> int:
        """The train sample nearest the mean parameter vector (each parameter scaled by its range)."""
        train = self.indices("train") or self.indices()
        if not len(self.space):
            return train[0]
        return train[select_template(self.space, [self._params[i] for i in train])]


def _coerce_shape(result: Any, name: str) -> Shape:
    """Accept a Shape, (vertices, faces), a dict with those keys, or a trimesh.Trimesh."""
    if isinstance(result, Shape):
        return result
    if isinstance(result, Mapping):
        missing = {"vertices", "faces"} - set(result)
        if missing:
            raise ValueError(f"generator {name!r} returned a dict without {sorted(missing)}")
        return Shape(
            np.asarray(result["vertices"], float),
            np.asarray(result["faces"], np.int64),
            canonical=result.get("canonical"),
            labels=result.get("labels"),
            label_names=tuple(result.get("label_names", ())),
        )
    if isinstance(result, tuple) and len(result) == 2:
        return Shape(np.asarray(result[0], float), np.asarray(result[1], np.int64))
    if hasattr(result, "vertices") and hasattr(result, "faces"):
        return Shape(np.asarray(result.vertices, float), np.asarray(result.faces, np.int64))
    raise ValueError(f"generator {name!r} returned {type(result).__name__}; expected a Shape, (vertices, faces), a dict or a mesh")


class PythonGenerator(ProceduralModel):
    """A user's generator function as a procedural model (black box: no canonical coordinates)."""

    def __init__(self, name: str, fn: Callable[[dict[str, Any]], Any], space: ParamSpace, description: str = "") -> None:
        self.name = name
        self.fn = fn
        self.space = space
        self.description = description or f"user generator {name}"

    def _build(self, params: dict[str, Any]) -> Shape:
        try:
            result = self.fn(dict(params))
        except Exception as exc:
            raise ValueError(f"generator {self.name!r} failed for {params}: {exc}") from exc
        return _coerce_shape(result, self.name)


def _import_module(spec: str, base: Path) -> Any:
    path = (base / spec) if not os.path.isabs(spec) else Path(spec)
    if spec.endswith(".py"):
        if not path.is_file():
            raise ValueError(f"generator module file {path} does not exist")
        return import_file(path, "proctex_user")
    try:
        return importlib.import_module(spec)
    except ImportError as exc:
        raise ValueError(f"cannot import generator module {spec!r}: {exc}") from exc


def read_config(path: str | os.PathLike) -> dict[str, Any]:
    """Parse a JSON or TOML config file into a dict (``ValueError`` on bad syntax)."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"{path}: no such config file")
    try:
        if p.suffix.lower() == ".toml":
            return tomllib.loads(p.read_text())
        return json.loads(p.read_text())
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: cannot parse config: {exc}") from exc


def load_generator(config_path: str | os.PathLike) -> PythonGenerator:
    """Build a :class:`PythonGenerator` from the ``[generator]`` section of a config file."""
    cfg = read_config(config_path)
    gen = cfg.get("generator")
    if not isinstance(gen, Mapping):
        raise ValueError(f"{config_path}: expected a [generator] section with module and function")
    for key in ("module", "function"):
        if not isinstance(gen.get(key), str) or not gen[key]:
            raise ValueError(f"{config_path}: generator.{key} must be a non-empty string")
    module = _import_module(gen["module"], Path(config_path).resolve().parent)
    fn = getattr(module, gen["function"], None)
    if not callable(fn):
        raise ValueError(f"{config_path}: {gen['module']} has no function {gen['function']!r}")
    specs = gen.get("params", getattr(module, "PARAMS", None))
    if specs is None:
        raise ValueError(f"{config_path}: give generator.params or a PARAMS list in the module")
    name = gen.get("name") or Path(gen["module"]).stem
    return PythonGenerator(str(name), fn, ParamSpace.from_list(specs), gen.get("description", ""))


def resolve_model(name_or_config: str) -> ProceduralModel:
    """A built-in model by name, or a user generator from a ``.json``/``.toml`` config path."""
    if name_or_config.endswith((".json", ".toml")):
        return load_generator(name_or_config)
    return get_model(name_or_config)


def resolve_shape(arg: str) -> Shape:
    """Shape from a CLI argument: a mesh file, a built-in model name, or ``MODEL:{json params}``."""
    if ":" in arg and arg.split(":", 1)[0] in list_models():
        name, raw = arg.split(":", 1)
        try:
            params = json.loads(raw) if raw.strip() else {}
        except json.JSONDecodeError as exc:
            raise ValueError(f"bad parameters for {name!r}: {exc}") from exc
        return get_model(name).generate(params)
    if arg in list_models():
        return get_model(arg).generate()
    if not os.path.exists(arg):
        raise ValueError(f"{arg!r} is neither a mesh file nor a built-in model ({', '.join(list_models())})")
    shape, _ = load_mesh(arg)
    pj = Path(arg).with_suffix(".json")
    if pj.is_file():
        shape.params = read_params(pj)
    return shape
