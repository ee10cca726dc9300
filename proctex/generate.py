"""Textured variants by the thousand (``proctex generate``): parameter rows in, one textured file per
row and a Parquet manifest out, resumable, into any ``pyarrow.fs`` URI.

The work is two stages over batches of rows, each a callable class so that whoever runs them (this
module's :func:`run_in_process`, or Ray Data's actor pools in ``workflows/generate.py``) loads the
family once per worker:

1. :class:`ShapeStage` makes each row's shape from its parameters (the family's procedural model);
   a row whose output is already complete is passed on as done, a row that cannot be made is
   recorded as failed.
2. :class:`TextureStage` transfers the family's textures onto each shape and writes the file (GLB,
   or OBJ + MTL + PNGs), then the row's record. Both writes are atomic and the record comes last,
   so a record means a complete output: a rerun skips those rows, and a killed run loses nothing.

The output folder (:class:`GenerateLayout`) holds ``generate.json`` (the run's settings and the
family's build stamp: a rerun must match them), ``variants/``, ``records/`` and ``manifest.parquet``
(one row per parameter row: parameters, file, counts, notes, seconds, status, error, and when it
finished).
"""

from __future__ import annotations

import io
import json
import os
import time
from dataclasses import asdict, dataclass, field
from typing import Any, Callable, Iterable

import numpy as np
import pyarrow as pa

from proctex.correspond.corrnet import resolve_device
from proctex.geometry.shape import Shape
from proctex.looks import LookLimits, add_look
from proctex.params import ParamSpace, restricted_space
from proctex.progress import Progress
from proctex.serve.service import FamilyService
from proctex.store.family import Family
from proctex.store.layout import FamilyStore, StoreLayout, check_look_name
from proctex.store.looks import built_look, look_paint, looks as family_looks, new_look_paint, other_looks, resolve_look
from proctex.store.state import stored_config
from proctex.texture.export import obj_files
from proctex.texture.painters.vocabulary import random_prompts

FORMATS = ("glb", "obj")
TEXTURE_MODES = ("embedded", "shared")
MAX_ROWS = 10_000_000
MAX_LOOKS = 64


class GenerateLayout:
    """Where a generate run keeps its files, relative to the output root."""

    RUN = "generate.json"
    MANIFEST = "manifest.parquet"

    @staticmethod
    def variant(vid: str, fmt: str) -> str:
        return f"variants/{vid}.{fmt}"

    @staticmethod
    def record(vid: str) -> str:
        return f"records/{vid}.json"

    @staticmethod
    def texture(name: str) -> str:
        """A texture every variant shares (``textures=shared``): ``textures/<group>[.<map>].png``."""
        return f"textures/{name}"

    #: how a variant (in ``variants/``) refers to the shared textures
    TEXTURE_LINK = "../textures/"


@dataclass(frozen=True)
class GenerateSettings:
    """What to generate.

    Attributes:
        family: the family store (path or URI); out: the output root (path or URI).
        n: rows to sample from the family's parameter space (Latin hypercube), or None with ``rows``.
        rows: a Parquet or CSV file of parameter rows (one column per parameter; missing or null
            values take the defaults), instead of ``n``.
        seed: sampling seed, and the base of each row's transfer seed.
        bounds: ``{name: [low, high]}`` narrowing float / int parameters for sampling.
        format: "glb" (self-contained) or "obj" (OBJ, MTL and PNGs per row).
        textures: "embedded" (every file carries its textures and PBR maps) or "shared" (GLB only,
            without ``bake``: the family's textures and maps are written once into ``textures/`` and
            every GLB refers to them, ``../textures/<g>.png``, so a variant is its geometry and UVs).
        bake: give each variant its own texture atlas of this size instead of the template's.
        max_failed: rows that may fail before the run stops.
        batch_size: rows per batch.
        device: where the networks run ("cpu", "cuda", "cuda:<i>").
        looks: the family's looks each shape is made in (:mod:`proctex.store.looks`; ``["all"]``:
            every look; None: the build's look): every parameter row crossed with them. A rows
            file's ``look`` column names a row's one look instead.
        random_looks: first give the family this many looks painted from prompts sampled from the
            painter's own vocabulary (:func:`proctex.texture.painters.vocabulary.random_prompts`,
            ``seed``), named ``random-<seed>-<k>``; each is then crossed with the shapes too.
    """

    family: str
    out: str
    n: int | None = None
    rows: str | None = None
    seed: int = 0
    bounds: dict[str, list[float]] = field(default_factory=dict)
    format: str = "glb"
    bake: int | None = None
    textures: str = "embedded"
    max_failed: int = 10
    batch_size: int = 8
    device: str = "cpu"
    looks: tuple[str, ...] | None = None
    random_looks: int = 0

    def validate(self) -> "GenerateSettings":
        if (self.n is None) == (self.rows is None):
            raise ValueError("give either n (rows to sample) or rows (a Parquet or CSV file of parameters)")
        for name in ("n", "seed", "max_failed", "batch_size") + (("bake",) if self.bake is not None else ()):
            value = getattr(self, name)
            if value is None:
                continue
            if not isinstance(value, int) or isinstance(value, bool):
                raise ValueError(f"{name} must be an integer, got {value!r}")
        if self.n is not None and not 1 <= self.n <= MAX_ROWS:
            raise ValueError(f"n must be in 1..{MAX_ROWS}, got {self.n}")
        if not 0 <= self.seed < 2**31:
            raise ValueError(f"seed must be in 0..2**31-1, got {self.seed}")
        if self.max_failed < 0 or not 1 <= self.batch_size <= 4096:
            raise ValueError(f"max_failed must be >= 0 and batch_size in 1..4096, got {self.max_failed}, {self.batch_size}")
        if self.bake is not None and not 8 <= self.bake <= 8192:
            raise ValueError(f"bake must be a texture size in 8..8192, got {self.bake}")
        if self.format not in FORMATS:
            raise ValueError(f"format must be one of {list(FORMATS)}, got {self.format!r}")
        if self.textures not in TEXTURE_MODES:
            raise ValueError(f"textures must be one of {list(TEXTURE_MODES)}, got {self.textures!r}")
        if self.textures == "shared" and (self.format != "glb" or self.bake):
            raise ValueError("shared textures are for GLB output with the template's textures (not obj, not bake)")
        if not isinstance(self.bounds, dict):
            raise ValueError('bounds must be an object {"name": [low, high]}')
        if self.looks is not None:
            if not self.looks or len(self.looks) > MAX_LOOKS or len(set(self.looks)) != len(self.looks):
                raise ValueError(f"looks must name 1 to {MAX_LOOKS} different looks (or 'all'), got {list(self.looks)[:8]}")
            for name in self.looks:
                if name != "all":
                    check_look_name(name)
            if "all" in self.looks and len(self.looks) > 1:
                raise ValueError("looks: 'all' stands alone")
        if isinstance(self.random_looks, bool) or not isinstance(self.random_looks, int) or not 0 <= self.random_looks <= MAX_LOOKS:
            raise ValueError(f"random_looks must be in 0..{MAX_LOOKS}, got {self.random_looks!r}")
        if self.rows is not None and self.bounds:
            raise ValueError("bounds narrow sampled rows; rows from a file are taken as they are")
        if "://" not in self.out and "://" not in self.family:
            fam, out = os.path.realpath(self.family), os.path.realpath(self.out)
            if out == fam or out.startswith(fam + os.sep):
                raise ValueError(f"the output {self.out} lies in the family {self.family}: give another folder")

        resolve_device(self.device)  # CUDA asked for and absent: said before any work
        return self

    def key(self) -> dict[str, Any]:
        """What a rerun into the same output must repeat (everything but the run's bounds on failures
        and batching)."""
        d = asdict(self)
        for k in ("out", "max_failed", "batch_size", "device"):
            d.pop(k)
        d["looks"] = list(self.looks) if self.looks is not None else None  # as JSON reads it back
        return d


def row_seed(seed: int, index: int) -> int:
    """The transfer seed of row ``index`` (new parts' paint): a fixed mix of the run's seed and the row."""
    return int((seed * 1_000_003 + index * 7_919) % (2**31 - 1))


def variant_id(index: int) -> str:
    return f"v{index:07d}"


# ------------------------------------------------------------------------------------------ rows
def family_space(family: FamilyStore) -> ParamSpace:
    """The parameter space of a family that can make shapes (a procedural model); ``ValueError``
    for a folder family."""
    model = stored_config(family).shapes().model
    if model is None:
        raise ValueError(f"{family.uri} is a folder family: it has no model to make new shapes from parameters")
    return model.space


def read_rows_file(path: str) -> list[dict[str, Any]]:
    """Parameter rows from a Parquet or CSV file: one dict per row, nulls left out."""
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    try:
        table = pq.read_table(path) if str(path).lower().endswith(".parquet") else pacsv.read_csv(path, convert_options=pacsv.ConvertOptions(strings_can_be_null=True))
    except (OSError, pa.ArrowException) as exc:
        raise ValueError(f"cannot read parameter rows from {path}: {exc}") from exc
    if table.num_rows > MAX_ROWS:
        raise ValueError(f"{path}: {table.num_rows} rows, more than {MAX_ROWS}")
    return [{k: v for k, v in row.items() if v is not None} for row in table.to_pylist()]


def plan_rows(settings: GenerateSettings, space: ParamSpace, looks: list[str] | None = None) -> list[dict[str, Any]]:
    """The run's rows: ``{"index", "id", "params" (JSON text), "seed", "look"}`` each: every parameter
    row in each of ``looks`` (default: ``[""]``, the build's look), or in the one look a rows file's
    ``look`` column names. One look: ids ``v<row>``; several: ``v<row>-<look>``; a shape's seed is
    the same in every look. Sampled rows lie in the (narrowed) space; rows from a file are checked
    later, row by row, so one bad row (an unknown look included) fails alone."""
    if settings.rows is not None:
        params = read_rows_file(settings.rows)
        if not params:
            raise ValueError(f"{settings.rows}: no rows")
    else:
        space = restricted_space(space, settings.bounds) if settings.bounds else space
        params = space.sample(settings.n, seed=settings.seed, method="lhs") if len(space) else [{} for _ in range(settings.n)]
    looks = looks or [""]
    rows = []
    for i, p in enumerate(params):
        own = p.pop("look", None) if isinstance(p, dict) else None
        for look in [str(own)] if own is not None else looks:
            rows.append(
                {
                    "index": len(rows),
                    "id": variant_id(i) + (f"-{look}" if len(looks) > 1 or own is not None else ""),
                    "params": json.dumps(p, sort_keys=True, default=_plain),
                    "seed": row_seed(settings.seed, i),
                    "look": look,
                }
            )
    return rows


def _plain(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"not JSON: {type(value).__name__}")


def start_run(settings: GenerateSettings, log: Callable[[str], None] = print) -> tuple[FamilyStore, list[dict[str, Any]], ParamSpace]:
    """Validate, read the family, plan the rows and write (or check) ``generate.json``: a rerun
    into an output made with other settings or another build of the family is refused.
    Returns ``(output store, rows, the family's parameter space)``."""
    settings.validate()
    family = FamilyStore(settings.family)

    if not family.exists(StoreLayout.STATE):
        raise ValueError(f"{settings.family}: no family here (no family.json)")
    space = family_space(family)
    if settings.random_looks:
        make_random_looks(family, settings.random_looks, settings.seed, log)

    looks = run_looks(family, settings) or [built_look(family).name]
    stamp = Family.open(family).version
    rows = plan_rows(settings, space, looks)
    out = FamilyStore(settings.out)
    run = {"settings": settings.key(), "stamp": stamp, "rows": len(rows)}
    if out.exists(GenerateLayout.RUN):
        before = out.read_json(GenerateLayout.RUN)
        if isinstance(before.get("settings"), dict):
            before["settings"].setdefault("textures", "embedded")  # runs recorded before shared textures existed
            before["settings"].setdefault("looks", None)  # and before looks
            before["settings"].setdefault("random_looks", 0)
        if before != run:
            diff = sorted(k for k in set(before.get("settings", {})) | set(run["settings"]) if before.get("settings", {}).get(k) != run["settings"].get(k))
            why = "the family was rebuilt or edited since" if before.get("stamp") != stamp else f"settings differ: {', '.join(diff) or 'rows'}"
            raise ValueError(f"{settings.out} holds another run ({why}); give a new --out")
        log(f"generate: resuming in {settings.out}")
    else:
        out.write_json(GenerateLayout.RUN, run)
    return out, rows, space


def run_looks(family: FamilyStore, settings: GenerateSettings) -> list[str] | None:
    """The looks a run crosses its shapes with (None: the build's look alone), each checked to exist
    (``ValueError`` listing the family's looks, before any work)."""
    names = list(settings.looks or [])
    if names == ["all"]:
        names = [lk.name for lk in family_looks(family)]
    if settings.random_looks:
        names += [random_look_name(settings.seed, k) for k in range(settings.random_looks) if random_look_name(settings.seed, k) not in names]
    for name in names:
        resolve_look(family, name)
    return names or None


def random_look_name(seed: int, k: int) -> str:
    return f"random-{seed}-{k}"


def make_random_looks(family: FamilyStore, n: int, seed: int, log: Callable[[str], None] = print) -> list[dict[str, Any]]:
    """Give ``family`` looks ``random-<seed>-0 .. n-1`` painted from :func:`random_prompts` (the
    build's other paint settings); a look of that name made before with the same prompt is kept,
    with another prompt it is a ``ValueError``. Returns each look's ``{"name", "prompt"}``."""
    paint = stored_config(family).paint
    have = {lk.name: lk for lk in other_looks(family)}
    out = []
    for k, prompt in enumerate(random_prompts(n, seed)):
        name = random_look_name(seed, k)
        if name in have:
            made = look_paint(family, have[name], paint).prompt
            if made != prompt:
                raise ValueError(f"the family's look {name} was painted with {made!r}, not {prompt!r}: remove it (proctex look rm) first")
        else:
            # the looks asked for are made whatever the family holds besides (the count bound is for looks added one by one)
            add_look(family, name, new_look_paint(paint, prompt), log=log, limits=LookLimits(looks=max(LookLimits().looks, len(have) + n)))
        out.append({"name": name, "prompt": prompt})
    return out


def batches(rows: list[dict[str, Any]], size: int) -> Iterable[dict[str, np.ndarray]]:
    """The rows as column batches (``{"index", "id", "params", "seed", "look"}`` arrays), ``size`` rows each."""
    for i in range(0, len(rows), size):
        chunk = rows[i : i + size]
        yield {k: np.array([r[k] for r in chunk], dtype=object if k in ("id", "params", "look") else np.int64) for k in ("index", "id", "params", "seed", "look")}


def _record(out: FamilyStore, vid: str, fmt: str) -> dict[str, Any] | None:
    """The row's record when its output is complete (the record written last, the file present)."""
    rel = GenerateLayout.record(vid)
    if not out.exists(rel):
        return None
    try:
        rec = out.read_json(rel)
    except ValueError:
        return None  # damaged: made again
    return rec if rec.get("status") == "written" and out.exists(rec.get("file", GenerateLayout.variant(vid, fmt))) else None


# ----------------------------------------------------------------------------------------- stages
MANIFEST_FIELDS = (
    "index",
    "id",
    "params",
    "look",
    "status",
    "file",
    "faces",
    "vertices",
    "parts",
    "groups",
    "notes",
    "error",
    "bytes",
    "generate_seconds",
    "transfer_seconds",
    "write_seconds",
    "finished",
)


def _empty(row: dict[str, Any]) -> dict[str, Any]:
    return {
        "index": int(row["index"]),
        "id": str(row["id"]),
        "params": str(row["params"]),
        "look": str(row.get("look", "")),
        "status": "",
        "file": "",
        "faces": 0,
        "vertices": 0,
        "parts": 0,
        "groups": 0,
        "notes": "[]",
        "error": "",
        "bytes": 0,
        "generate_seconds": 0.0,
        "transfer_seconds": 0.0,
        "write_seconds": 0.0,
        "finished": time.time(),
    }


def _rows_of(batch: dict[str, np.ndarray]) -> list[dict[str, Any]]:
    keys = list(batch)
    return [{k: batch[k][i] for k in keys} for i in range(len(batch[keys[0]]))] if keys else []


def _columns(rows: list[dict[str, Any]], fields: tuple[str, ...]) -> dict[str, np.ndarray]:
    out = {}
    for k in fields:
        values = [r[k] for r in rows]
        out[k] = np.array(values, dtype=object) if values and isinstance(values[0], (str, bytes)) else np.array(values)
    return out


class ShapeStage:
    """Stage 1: parameters to shapes. A callable over column batches (see :func:`batches`) that adds
    ``status`` ("made", "done" for a complete earlier output, "failed"), ``mesh`` (the shape as
    ``.npz`` bytes, empty unless made), ``record`` (a done row's record as JSON text, else empty),
    ``error`` and ``generate_seconds``."""

    FIELDS = ("index", "id", "params", "seed", "look", "status", "mesh", "record", "error", "generate_seconds")

    def __init__(self, family: str, out: str, fmt: str = "glb") -> None:
        self.model = stored_config(FamilyStore(family)).procedural_model()
        self.out, self.fmt = FamilyStore(out), fmt

    def __call__(self, batch: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        rows = []
        for row in _rows_of(batch):
            row = {"look": "", **row, "status": "made", "mesh": b"", "record": "", "error": "", "generate_seconds": 0.0}
            rec = _record(self.out, str(row["id"]), self.fmt)
            if rec is not None:
                row.update(status="done", record=json.dumps(rec))
            else:
                t0 = time.perf_counter()
                try:
                    shape = self.model.generate(json.loads(str(row["params"])))
                    buf = io.BytesIO()
                    np.savez(buf, vertices=shape.vertices, faces=shape.faces)
                    row["mesh"] = buf.getvalue()
                except (ValueError, TypeError, OverflowError, json.JSONDecodeError) as exc:
                    row.update(status="failed", error=f"{type(exc).__name__}: {exc}"[:500])
                row["generate_seconds"] = time.perf_counter() - t0
            rows.append(row)
        return _columns(rows, self.FIELDS)


class TextureStage:
    """Stage 2: shapes to textured files. A callable over :class:`ShapeStage`'s batches that writes
    each made row's file and record and returns manifest rows (:data:`MANIFEST_FIELDS`); rows done
    earlier come back from their records."""

    def __init__(self, family: str, out: str, fmt: str = "glb", bake: int | None = None, device: str = "cpu", textures: str = "embedded") -> None:
        self.svc = FamilyService(FamilyStore(family), device=device)
        self.out, self.fmt, self.bake, self.textures = FamilyStore(out), fmt, bake, textures
        self._shared: set[str] = set()  # looks whose shared textures this worker has written

    def service(self, look: str) -> Any:
        """The family's service in ``look`` ("": the build's), its shared textures written first
        (``textures/``, another look's in ``textures/<look>/``: once per worker, atomically and
        identically, so concurrent writers agree)."""
        svc = self.svc.look_view(look or None)
        if self.textures == "shared" and look not in self._shared:
            for name, data in svc.shared_textures().items():
                rel = GenerateLayout.texture(f"{look}/{name}" if look and not svc.look.built else name)
                if not self.out.exists(rel) or self.out.read_bytes(rel) != data:
                    self.out.write_bytes(rel, data)
            self._shared.add(look)
        return svc

    def __call__(self, batch: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        rows = []
        for row in _rows_of(batch):
            entry = _empty(row)
            entry["generate_seconds"] = float(row["generate_seconds"])
            if row["status"] == "done":
                entry = {**entry, **json.loads(str(row["record"])), "status": "done"}
            elif row["status"] == "failed":
                entry.update(status="failed", error=str(row["error"]))
            else:
                entry.update(self._make(row))
            rows.append(entry)
        return _columns(rows, MANIFEST_FIELDS)

    def _make(self, row: dict[str, Any]) -> dict[str, Any]:
        vid, look = str(row["id"]), str(row.get("look", ""))
        t0 = time.perf_counter()
        try:
            svc = self.service(look)
            with np.load(io.BytesIO(bytes(row["mesh"])), allow_pickle=False) as z:
                shape = Shape(z["vertices"], z["faces"])
            link = (GenerateLayout.TEXTURE_LINK + (f"{look}/" if look and not svc.look.built else "")) if self.textures == "shared" else None
            answer, summary = svc.textured(shape, seed=int(row["seed"]), bake_size=self.bake, linked=link is not None, link_base=link)
        except (ValueError, TypeError, OverflowError) as exc:  # a row's unknown look (NotFound) included
            return {"status": "failed", "error": f"{type(exc).__name__}: {exc}"[:500], "transfer_seconds": time.perf_counter() - t0, "finished": time.time()}
        t1 = time.perf_counter()
        files = self._files(vid, shape, answer)
        main = GenerateLayout.variant(vid, self.fmt)
        for rel, data in files:  # the main file last: what it names exists before it does
            self.out.write_bytes(rel, data)
        rec = {
            "index": int(row["index"]),
            "id": vid,
            "params": str(row["params"]),
            "look": look or svc.look.name,
            "status": "written",
            "file": main,
            "faces": shape.n_faces,
            "vertices": shape.n_vertices,
            "parts": len(answer.result.assignment),  # one entry per part
            "groups": int(len(set(answer.face_group[answer.face_group >= 0].tolist()))),
            "notes": json.dumps(summary.get("notes", [])),
            "error": "",
            "bytes": int(sum(len(d) for _, d in files)),
            "generate_seconds": float(row["generate_seconds"]),
            "transfer_seconds": t1 - t0,
            "write_seconds": 0.0,
        }
        rec["write_seconds"] = time.perf_counter() - t1
        rec["finished"] = time.time()  # wall clock: throughput over a run, across workers
        self.out.write_json(GenerateLayout.record(vid), rec)
        return rec

    def _files(self, vid: str, shape, answer) -> list[tuple[str, bytes]]:
        """``[(relative path, bytes)]`` of the row's output, the main file last."""
        if self.fmt == "glb":
            return [(GenerateLayout.variant(vid, "glb"), answer.data)]

        names = self.svc.assets.names + [f"new_{k}" for k in range(len(answer.textures) - len(self.svc.assets.names))]  # every look's
        pbr = answer.pbr if answer.pbr is not None and any(m is not None for m in answer.pbr) else None  # MTL names the PBR maps too
        made = obj_files(vid, shape.vertices, shape.faces, answer.corner_uv, answer.face_group, answer.textures, names=names[: len(answer.textures)], pbr=pbr)
        return [(f"variants/{name}", data) for name, data in made]


# ------------------------------------------------------------------------------------ the driver
class Tally:
    """Counts rows as they finish, prints progress (rate, ETA) and stops the run past ``max_failed``."""

    def __init__(self, total: int, max_failed: int, quiet: bool = False) -> None:
        self.progress = Progress("generate", total, quiet=quiet, interval=2.0)
        self.max_failed, self.rows, self.failed = max_failed, [], []

    def add(self, batch: dict[str, np.ndarray]) -> None:
        rows = _rows_of(batch)
        self.rows.extend(rows)
        self.failed.extend(r for r in rows if r["status"] == "failed")
        if len(self.failed) > self.max_failed:
            first = "; ".join(f"{r['id']}: {r['error']}" for r in self.failed[:3])
            raise ValueError(f"{len(self.failed)} rows failed, more than max_failed={self.max_failed}; the first: {first}")
        self.progress.update(len(rows))


def finish(out: FamilyStore, rows: list[dict[str, Any]], space: ParamSpace | None = None) -> dict[str, Any]:
    """Write ``manifest.parquet`` (rows by index; each parameter also as a ``param.<name>`` column)
    and return the run's summary. Every row has finished by now: a temporary still in the output is
    a killed writer's (its row written again by the retry), and is removed."""
    for folder in ("variants", "records", "textures"):
        out.remove_temporaries(folder)
    rows = sorted(rows, key=lambda r: int(r["index"]))
    table = {k: [(_py(r[k])) for r in rows] for k in MANIFEST_FIELDS}
    if space is not None:
        parsed = [json.loads(str(r["params"])) if r["status"] != "failed" else {} for r in rows]
        for spec in space.specs:
            table[f"param.{spec.name}"] = [p.get(spec.name) for p in parsed]
    out.write_table(GenerateLayout.MANIFEST, pa.table(table))
    status = [r["status"] for r in rows]
    return {"rows": len(rows), "written": status.count("written"), "done_before": status.count("done"), "failed": status.count("failed"), "manifest": out.uri_of(GenerateLayout.MANIFEST)}


def _py(value: Any) -> Any:
    return value.item() if isinstance(value, np.generic) else value


def run_in_process(settings: GenerateSettings, log: Callable[[str], None] = print, quiet: bool = False) -> dict[str, Any]:
    """The whole run in this process, batch after batch (the files equal the Ray run's)."""
    t0 = time.perf_counter()
    out, rows, space = start_run(settings, log)
    shapes = ShapeStage(settings.family, settings.out, settings.format)
    textures = TextureStage(settings.family, settings.out, settings.format, settings.bake, settings.device, settings.textures)
    tally = Tally(len(rows), settings.max_failed, quiet)
    for batch in batches(rows, settings.batch_size):
        tally.add(textures(shapes(batch)))
    summary = finish(out, tally.rows, space)
    return {**summary, "seconds": round(time.perf_counter() - t0, 3)}
