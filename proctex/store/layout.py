"""The family store (docs/architecture.md): a folder or a ``pyarrow.fs`` URI that fully describes a family.

Every write is atomic. In a folder the bytes go to a temporary name next to the target, which is then
renamed (``pyarrow.fs.FileSystem.move``), so a crash never leaves a half-written file under the real
name. On an object store (``s3://``) an object appears whole or not at all (a single PUT, or a
multipart upload that only its completion makes visible), so the bytes go to the real name at once
(a rename there would be a copy and a delete). Readers only ever see complete files. Tables are
Parquet, arrays ``.npz`` (no pickles), documents JSON.

Layout (all paths relative to the root; :class:`StoreLayout` is the one place that spells them)::

    family.json            config, stage states, package versions
    samples.parquet        one row per sampled shape
    meshes/<id>.obj        sampled meshes (and <id>.json, each sample job's record)
    template/              template mesh, grouping, UVs, textures, textured.glb
    pairs.parquet          one row per (shape, group) correspondence job
    correspondences/       one Parquet table of (source point, template point) per pair (and, for
                           test shapes, where the cage sends the part's vertices: the cage tracker's)
    models/                one ProcCorrNet per group
    metrics.json           evaluation
"""

from __future__ import annotations

import contextlib
import errno
import io
import json
import os
import re
import threading
import uuid
import zipfile
from typing import Any, Callable, Iterator

import numpy as np
import pyarrow as pa
import pyarrow.fs as pafs
import pyarrow.parquet as pq

#: the PBR maps a group texture may have besides its base colour (file ``group_<g>[_<label>].<kind>.png``).
MAP_KINDS = ("orm", "normal")


def group_file_name(group: int, label: str, kind: str = "") -> str:
    """``group_<index>[_<label>].png`` (label made file-name safe): a group texture's file name; with
    ``kind`` (one of :data:`MAP_KINDS`) the name of that PBR map, ``group_<index>[_<label>].<kind>.png``
    (labels never hold a dot, so no label makes a map's name)."""
    safe = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in label)
    if kind and kind not in MAP_KINDS:
        raise ValueError(f"map kind must be one of {', '.join(MAP_KINDS)}, got {kind!r}")
    return f"group_{group}{'_' + safe if safe else ''}{'.' + kind if kind else ''}.png"


def digest(data: bytes) -> str:
    """The checksum a record keeps of a store file: the first 16 hex digits of its SHA-256."""
    import hashlib

    return hashlib.sha256(data).hexdigest()[:16]


def check_digest(data: bytes, expected: str | None, where: str) -> None:
    """:class:`StoreDamaged` (a ``ValueError``) naming ``where`` when ``data`` does not have the
    recorded checksum (None: none was recorded, as in stores written before checksums)."""
    if expected is not None and digest(data) != expected:
        raise StoreDamaged(f"{where}: checksum mismatch (recorded {expected}, found {digest(data)}): the file changed outside ProcTex")


class StoreWriteError(OSError):
    """A store write that did not land (a full disk, no permission): ``errno`` says which, the
    message names the file; nothing of the change it belonged to was written."""

    @classmethod
    def of(cls, exc: OSError, where: str) -> "StoreWriteError":
        text = str(exc)
        code = exc.errno or (errno.ENOSPC if "No space left" in text else errno.EACCES if "ermission denied" in text else errno.EIO)
        why = {
            errno.ENOSPC: "no space left on the store's disk",
            errno.EACCES: "permission denied",
            errno.EPERM: "permission denied",
            errno.EROFS: "the store is read-only",
            errno.EDQUOT: "over the disk quota",
        }.get(code, text[:200])
        return cls(code, f"cannot write {where}: {why}; nothing was changed")


class StoreUnreachable(OSError):
    """An object store that did not answer within the wait (``PROCTEX_STORE_WAIT`` seconds)."""


#: Seconds an operation on an object store waits for the store to come back (``PROCTEX_STORE_WAIT``).
STORE_WAIT = 600.0
#: What an unreachable (or overloaded) object store says, as pyarrow and botocore word it.
UNREACHABLE = (
    "NETWORK_CONNECTION",
    "curlCode: 7,",
    "curlCode: 28,",
    "Could not connect",
    "Connection refused",
    "Connect timeout",
    "SERVICE_UNAVAILABLE",
    "SLOW_DOWN",
    "Could not connect to the endpoint",
    "Read timeout",
    "Connection was closed",
)


def unreachable(exc: BaseException) -> bool:
    """Whether ``exc`` says the object store did not answer (down, restarting, overloaded), rather
    than that the request was wrong (a missing key, no permission)."""
    text = f"{type(exc).__name__}: {exc}"
    if type(exc).__name__ in ("EndpointConnectionError", "ConnectTimeoutError", "ReadTimeoutError", "ConnectionClosedError"):
        return True  # botocore's
    code = getattr(exc, "response", None)
    if isinstance(code, dict) and code.get("Error", {}).get("Code") in ("SlowDown", "ServiceUnavailable", "503", "InternalError"):
        return True
    return isinstance(exc, (OSError, ConnectionError)) and not isinstance(exc, StoreWriteError) and any(k in text for k in UNREACHABLE)


def store_wait() -> float:
    """``PROCTEX_STORE_WAIT`` (seconds, 0..86400; default :data:`STORE_WAIT`); ``ValueError`` otherwise."""
    raw = os.environ.get("PROCTEX_STORE_WAIT", "")
    try:
        wait = float(raw) if raw.strip() else STORE_WAIT
    except ValueError:
        wait = -1.0
    if not 0.0 <= wait <= 86400.0:  # NaN fails too
        raise ValueError(f"PROCTEX_STORE_WAIT must be seconds in 0..86400, got {raw[:40]!r}")
    return wait


def wait_for(uri: str, what: str, fn, log=None):
    """``fn()``, again (backing off from 0.5 to 10 s) while it fails because the object store at
    ``uri`` does not answer (:func:`unreachable`), for up to ``PROCTEX_STORE_WAIT`` seconds (default
    600); each wait is said on stderr (what it waits for, and for how long so far). Then
    :class:`StoreUnreachable`. Any other error is raised at once."""
    import sys
    import time

    start = None
    delay = 0.5
    while True:
        try:
            return fn()
        except Exception as exc:
            if not unreachable(exc):
                raise
            now = time.monotonic()
            if start is None:
                start, wait = now, store_wait()
            short = str(exc).split("; Details")[0][-160:]
            if now - start >= wait:
                raise StoreUnreachable(errno.EHOSTUNREACH, f"{uri}: the object store did not answer for {wait:.0f} s ({what}): {short}") from exc
            (log or (lambda m: print(m, file=sys.stderr, flush=True)))(
                f"store {uri}: the object store does not answer ({short}); waiting for it to come back to {what} ({now - start:.0f} s of {wait:.0f} s)"
            )
            time.sleep(delay)
            delay = min(delay * 2, 10.0)


_FENCES = threading.local()


@contextlib.contextmanager
def fence(base: str, check: Callable[[], None]) -> Iterator[None]:
    """While the block runs, every write and delete this thread makes on the object store at
    ``base`` first calls ``check`` (a lease's: it raises once the lease may have expired, so a holder
    cut off from the store writes nothing after another may have taken its lease)."""
    checks = _FENCES.__dict__.setdefault("checks", [])
    entry = (base, check)
    checks.append(entry)
    try:
        yield
    finally:
        checks.remove(entry)


def check_fences(base: str) -> None:
    """Run this thread's fences on the store at ``base`` (:func:`fence`)."""
    for where, check in list(getattr(_FENCES, "checks", ())):
        if where == base:
            check()


class StoreDamaged(ValueError):
    """A store file that is not what its record says (changed outside ProcTex, or damaged)."""


def encode_arrays(**arrays: np.ndarray) -> bytes:
    """``.npz`` bytes of numeric arrays (no object arrays: loading never unpickles)."""
    for k, a in arrays.items():
        if np.asarray(a).dtype == object:
            raise ValueError(f"array {k!r} has dtype object; only numeric arrays are stored")
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


#: The paint record's file name, in a look's folder.
PAINT_NAME = "paint.json"
#: The name of a family's first look (the one its build paints) unless the build named it.
DEFAULT_LOOK = "default"
#: A look's name: what a family's name may be (letters, digits, ``.``, ``_``, ``-``; 64 at most).
LOOK_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")


def check_look_name(name: Any) -> str:
    """``name`` when it can name a look (:data:`LOOK_NAME`), else a ``ValueError`` saying what can."""
    if not isinstance(name, str) or not LOOK_NAME.fullmatch(name) or ".tmp-" in name:  # .tmp-: a staging name
        raise ValueError(f"a look's name is 1-64 letters, digits, '.', '_' or '-' (starting with a letter or digit), got {str(name)[:80]!r}")
    return name


class LookLayout:
    """Where one look of a family lies (relative to the store root): its paint record
    (``paint.json``), group textures and PBR maps, painted masks, textured GLB, preview and edit
    snapshots. The build's look lies in ``template/`` (where every store before looks kept it);
    every other look in ``looks/<name>/``, with its record ``look.json`` (written last: a look
    without it was never finished)."""

    def __init__(self, name: str = DEFAULT_LOOK, folder: str = "template") -> None:
        self.name, self.folder = name, folder
        self.PAINT = f"{folder}/{PAINT_NAME}"
        self.PAINTED = f"{folder}/painted.npz"
        self.GLB = f"{folder}/textured.glb"
        self.EDITS = f"{folder}/edits"
        self.RECORD = f"{folder}/look.json"

    def __repr__(self) -> str:
        return f"LookLayout({self.name!r}, {self.folder!r})"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, LookLayout) and (self.name, self.folder) == (other.name, other.folder)

    def __hash__(self) -> int:
        return hash((self.name, self.folder))

    @property
    def built(self) -> bool:
        """Whether this is the build's look (in ``template/``)."""
        return self.folder == StoreLayout.TEMPLATE

    def file(self, name: str) -> str:
        """A file of the look's folder."""
        return f"{self.folder}/{name}"

    def texture(self, group: int, label: str, kind: str = "") -> str:
        """A group's texture, or with ``kind`` one of its PBR maps (:func:`group_file_name`)."""
        return self.file(group_file_name(group, label, kind))

    def edit_snapshot(self, version: int, name: str) -> str:
        """A file as it was before edit ``version`` (``name``: a file name of the look)."""
        return f"{self.EDITS}/v{int(version):05d}/{name}"


class StoreLayout:
    """Every path of a family store (relative to its root), and nothing else spells them."""

    STATE = "family.json"
    SAMPLES = "samples.parquet"
    PAIRS = "pairs.parquet"
    METRICS = "metrics.json"
    MODELS = "models"
    TEMPLATE = "template"
    TEMPLATE_MESH = "template/template.obj"
    TEMPLATE_SHAPE = "template/shape.npz"  # the template shape whole (labels, part names): read, never regenerated
    UV = "template/uv.npz"
    GROUPING = "template/grouping.json"
    PART_WORDS = "template/part_words.json"  # the user's word per group (proctex parts --assign, the studio)
    PAINT_NAME = PAINT_NAME  # the painter's summary, in the folder it writes (a look's folder)
    # The build's look (in template/): its paths are the LookLayout's, spelled there once.
    _BUILT = LookLayout(DEFAULT_LOOK, "template")
    TEMPLATE_GLB = _BUILT.GLB
    PAINT = _BUILT.PAINT
    PAINTED = _BUILT.PAINTED
    EDITS = _BUILT.EDITS  # one folder per stored edit: the files it replaced (its undo)
    edit_snapshot = staticmethod(_BUILT.edit_snapshot)  # a file as it was before edit ``version``
    template_file = staticmethod(_BUILT.file)  # a file of the template folder (the painter's outputs)
    texture = staticmethod(_BUILT.texture)  # a group's texture, or with ``kind`` one of its PBR maps
    LOOKS = "looks"  # one folder per look besides the build's (LookLayout)
    EDIT_LOCK = ".edit.lock"  # held while an edit changes the store (local stores)
    BUILD_LOCK = ".build.lock"  # held while a build runs (exclusive) or an edit (shared)

    @staticmethod
    def look(name: str, built: bool = False) -> LookLayout:
        """The layout of look ``name``: the build's (``built``, in ``template/``) or another
        (``looks/<name>/``, the name checked)."""
        if built:
            return LookLayout(name, StoreLayout.TEMPLATE)
        return LookLayout(check_look_name(name), f"{StoreLayout.LOOKS}/{name}")

    @staticmethod
    def mesh(sid: str) -> str:
        """A sampled mesh."""
        return f"meshes/{sid}.obj"

    @staticmethod
    def sample_record(sid: str) -> str:
        """A sample job's record (written after its mesh)."""
        return f"meshes/{sid}.json"

    @staticmethod
    def pair(sid: str, group: int) -> str:
        """A cage pair's table of (source point, template point)."""
        return f"correspondences/{sid}__g{group}.parquet"

    @staticmethod
    def pair_vertices(sid: str, group: int) -> str:
        """Where a test pair's cage sends its source part's vertices (written before its table):
        the evaluation's cage tracker reads them instead of solving the pair again."""
        return f"correspondences/{sid}__g{group}.vertices.npz"

    @staticmethod
    def pair_record(sid: str, group: int) -> str:
        """A pair job's record (written after its table)."""
        return f"correspondences/{sid}__g{group}.json"

    @staticmethod
    def model(group: int) -> str:
        """A group's ProcCorrNet checkpoint."""
        return f"models/group_{group}.pt"

    @staticmethod
    def model_group(name: str) -> int | None:
        """The group of a file name in ``models/`` (``group_<g>.pt``), None for anything else."""
        stem = name[len("group_") : -len(".pt")] if name.startswith("group_") and name.endswith(".pt") else ""
        return int(stem) if stem.isdigit() else None


class FamilyStore:
    """Atomic reads and writes under a root folder or URI (``s3://bucket/prefix``, ``file:///...``)."""

    def __init__(self, root: str | os.PathLike) -> None:
        uri = os.fspath(root)
        if not uri:
            raise ValueError("family store root must not be empty")
        if "://" in uri:
            opened = uri
            if uri.lower().startswith("s3://") and "allow_delayed_open" not in uri:  # a small object: one PUT at close, not three requests
                opened = uri + ("&" if "?" in uri else "?") + "allow_delayed_open=true"
            try:
                self.fs, self.base = pafs.FileSystem.from_uri(opened)
            except (pa.ArrowInvalid, OSError) as exc:
                raise ValueError(f"cannot open family store {uri!r}: {exc}") from exc
        else:
            self.fs, self.base = pafs.LocalFileSystem(), os.path.abspath(uri)
        self.uri = uri
        #: whether the store is a folder (renames, file locks) rather than an object store
        self.local = self.fs.type_name == "local"

    def child(self, name: str) -> "FamilyStore":
        """The store at ``name`` under this root (a URI's query, such as ``?endpoint_override=``,
        kept after the path)."""
        if not name or "/" in name or name in (".", ".."):
            raise ValueError(f"bad store name {name!r}")
        if "://" not in self.uri:
            return FamilyStore(os.path.join(self.uri, name))
        head, sep, query = self.uri.partition("?")
        return FamilyStore(f"{head.rstrip('/')}/{name}{sep}{query}")

    def __repr__(self) -> str:
        return f"FamilyStore({self.uri!r})"

    # ------------------------------------------------------------------------------------- paths
    def path(self, rel: str) -> str:
        """Absolute path (in the store's file system) of a relative name; refuses escapes."""
        rel = str(rel).replace("\\", "/")
        parts = [p for p in rel.split("/") if p not in ("", ".")]
        if not parts or any(p == ".." for p in parts):
            raise ValueError(f"bad store path {rel!r}")
        return "/".join([self.base.rstrip("/")] + parts)

    def uri_of(self, rel: str) -> str:
        """What a user names a file of the store by: its path in a folder, its URI (``s3://...``,
        the query kept) in an object store."""
        full = self.path(rel)
        if "://" not in self.uri:
            return full
        head, sep, query = self.uri.partition("?")
        return f"{head.rstrip('/')}/{full[len(self.base.rstrip('/')) + 1 :]}{sep}{query}"

    def _io(self, what: str, fn):
        """``fn()``; on an object store, waiting for the store while it does not answer (:func:`wait_for`)."""
        return fn() if self.local else wait_for(self.uri, what, fn)

    def exists(self, rel: str) -> bool:
        p = self.path(rel)
        return self._io(f"look up {rel}", lambda: self.fs.get_file_info(p).type != pafs.FileType.NotFound)

    def listdir(self, rel: str = "") -> list[str]:
        """Names directly under a folder (``""``: the root; empty if missing), sorted."""
        where = self.base.rstrip("/") if rel in ("", ".") else self.path(rel)
        info = self._io(f"list {rel or 'the root'}", lambda: self.fs.get_file_info(pafs.FileSelector(where, allow_not_found=True)))
        return sorted(os.path.basename(i.path) for i in info if ".tmp-" not in os.path.basename(i.path))

    def delete(self, rel: str) -> None:
        p = self.path(rel)

        def delete() -> None:
            if not self.local:
                check_fences(self.base)  # each try: a wait for the store may outlast a lease
            t = self.fs.get_file_info(p).type
            if t == pafs.FileType.Directory:
                self.fs.delete_dir(p)
            elif t == pafs.FileType.File:
                self.fs.delete_file(p)

        self._io(f"delete {rel}", delete)

    # ------------------------------------------------------------------------------------- bytes
    def write_bytes(self, rel: str, data: bytes) -> str:
        """Write atomically (temporary name, then rename: :meth:`write_all` of one file); returns
        the full path."""
        return self.write_all([(rel, data)])[0]

    def write_all(self, files: list[tuple[str, bytes]]) -> list[str]:
        """Write several files as one change: every file is first written under a temporary name
        (what needs space), then each is renamed into place, in order (renames need none). A write
        that fails (a full disk, no permission) leaves the store as it was, every temporary removed,
        and raises :class:`StoreWriteError` naming the file. Returns the full paths.

        On an object store each file is one complete object written under its name, in order; when a
        write fails, the objects this change already wrote are put back as they were (or removed,
        where there was none) before the error is raised."""
        if not self.local:
            return self._put_all(files)
        staged: list[tuple[str, str]] = []
        made: list[str] = []  # folders this change created, outermost first: removed again when it fails
        try:
            for rel, data in files:
                final = self.path(rel)
                made += self._make_dirs(final.rsplit("/", 1)[0])
                tmp = f"{final}.tmp-{uuid.uuid4().hex[:12]}"
                staged.append((tmp, final))
                with self.fs.open_output_stream(tmp) as fh:
                    fh.write(data)
        except OSError as exc:
            self._remove(t for t, _ in staged)
            self._remove_dirs(made)
            raise StoreWriteError.of(exc, staged[-1][1] if staged else self.uri) from exc
        except BaseException:
            self._remove(t for t, _ in staged)
            self._remove_dirs(made)
            raise
        for k, (tmp, final) in enumerate(staged):
            try:
                self.fs.move(tmp, final)
            except BaseException:  # a rename that fails (rarely): no temporary is left behind
                self._remove(t for t, _ in staged[k:])
                raise
        return [final for _, final in staged]

    def _make_dirs(self, folder: str) -> list[str]:
        """Create ``folder`` (a full path) and its missing parents; returns those created, outermost first."""
        missing = []
        at = folder
        while at and at not in ("/", ".") and self.fs.get_file_info(at).type == pafs.FileType.NotFound:
            missing.append(at)
            parent = at.rsplit("/", 1)[0] if "/" in at else ""
            if parent == at:
                break
            at = parent
        if missing:
            self.fs.create_dir(folder, recursive=True)
        return missing[::-1]

    def _remove_dirs(self, made: list[str]) -> None:
        """Remove the folders a failed change created (innermost first), each only while empty."""
        for d in reversed(made):
            try:
                if not self.fs.get_file_info(pafs.FileSelector(d)):
                    self.fs.delete_dir(d)
            except OSError:
                pass

    def replace_folder(self, folder: str, files: list[tuple[str, bytes]]) -> None:
        """Make ``folder`` hold exactly ``files`` (paths relative to the store, all under ``folder``;
        the one that says the folder is complete last). In a folder store: written under a staging
        name beside it, then moved into place (a crash leaves the old folder or the new one, and no
        staging folder is listed). On an object store, which moves no folder: the old folder
        deleted, then the files written in order (the caller holds the lock readers check)."""
        folder = folder.rstrip("/")
        if any(not rel.startswith(folder + "/") for rel, _ in files):
            raise ValueError(f"every file of {folder}/ must lie in it")
        if not self.local:
            if self.exists(folder):
                self.delete(folder)
            self.write_all(files)
            return
        staging = f"{folder}.tmp-{uuid.uuid4().hex[:8]}"
        try:
            self.write_all([(staging + rel[len(folder) :], data) for rel, data in files])
            if self.exists(folder):
                self.delete(folder)
            self.fs.move(self.path(staging), self.path(folder))
        finally:
            if self.exists(staging):
                self.delete(staging)

    def _put_all(self, files: list[tuple[str, bytes]]) -> list[str]:
        """:meth:`write_all` on an object store: in order, undone on failure (what each object held
        is read first when the change has several files)."""
        if len(files) == 1:
            return [self._put(*files[0])]
        before = [(rel, self.read_bytes(rel) if self.exists(rel) else None) for rel, _ in files]
        done: list[int] = []
        try:
            for k, (rel, data) in enumerate(files):
                self._put(rel, data)
                done.append(k)
        except BaseException:
            for k in reversed(done):  # put back what this change replaced (best effort: the original error is the one raised)
                rel, old = before[k]
                try:
                    self._put(rel, old) if old is not None else self.delete(rel)
                except Exception:
                    pass
            raise
        return [self.path(rel) for rel, _ in files]

    def _put(self, rel: str, data: bytes) -> str:
        """One object written whole under its name (an object store's write is atomic), after this
        thread's fences on the store (:func:`fence`)."""
        final = self.path(rel)

        def put() -> None:
            check_fences(self.base)  # each try: a wait for the store may outlast a lease
            with self.fs.open_output_stream(final) as fh:
                fh.write(data)

        try:
            self._io(f"write {rel}", put)
        except StoreUnreachable:
            raise
        except OSError as exc:
            raise StoreWriteError.of(exc, final) from exc
        return final

    def remove_temporaries(self, folder: str) -> int:
        """Remove the temporaries (``*.tmp-*`` files) a writer killed between writing and renaming
        left directly under ``folder`` (relative; missing: nothing to do). Only for a caller that
        knows no writer of that folder is running (the end of a run that owns it). Returns how many
        were removed; an object store, written without temporaries, has none."""
        if not self.local:
            return 0
        info = self.fs.get_file_info(pafs.FileSelector(self.path(folder), allow_not_found=True))
        stale = [i.path for i in info if i.type == pafs.FileType.File and ".tmp-" in os.path.basename(i.path)]
        self._remove(stale)
        return len(stale)

    def _remove(self, paths) -> None:
        for p in paths:
            try:
                if self.fs.get_file_info(p).type == pafs.FileType.File:
                    self.fs.delete_file(p)
            except OSError:
                pass  # a temporary we could not remove is skipped by listdir and overwritten by no one

    def read_bytes(self, rel: str) -> bytes:
        p = self.path(rel)
        if not self.exists(rel):
            raise ValueError(f"{self.uri}: {rel} not found")

        def read() -> bytes:
            with self.fs.open_input_stream(p) as fh:
                return fh.read()

        return self._io(f"read {rel}", read)

    # ---------------------------------------------------------------------------------- formats
    def write_json(self, rel: str, data: Any) -> str:
        return self.write_bytes(rel, (json.dumps(data, indent=1, sort_keys=False) + "\n").encode())

    def read_json(self, rel: str) -> Any:
        try:
            return json.loads(self.read_bytes(rel))
        except json.JSONDecodeError as exc:
            raise StoreDamaged(f"{self.uri}: {rel} is not valid JSON ({exc})") from exc

    def write_table(self, rel: str, table: pa.Table | dict[str, Any]) -> str:
        """Write a Parquet table (a ``pa.Table`` or a dict of columns)."""
        if not isinstance(table, pa.Table):
            table = pa.table(table)
        buf = pa.BufferOutputStream()
        pq.write_table(table, buf)
        return self.write_bytes(rel, buf.getvalue().to_pybytes())

    def read_table(self, rel: str) -> pa.Table:
        """A Parquet table; ``ValueError`` naming the file when it is damaged."""
        data = self.read_bytes(rel)
        try:
            return pq.read_table(pa.BufferReader(data))
        except (pa.ArrowException, OSError) as exc:
            raise StoreDamaged(f"{self.uri}: {rel} is not a readable Parquet table ({exc.__class__.__name__})") from exc

    def write_arrays(self, rel: str, **arrays: np.ndarray) -> str:
        """Write numeric arrays as ``.npz`` (no object arrays: loading never unpickles)."""
        return self.write_bytes(rel, encode_arrays(**arrays))

    def read_arrays(self, rel: str) -> dict[str, np.ndarray]:
        """Arrays of an ``.npz`` (never unpickled); ``ValueError`` naming the file when it is damaged."""
        return self.read_arrays_of(self.read_bytes(rel), rel)

    def read_arrays_of(self, data: bytes, rel: str) -> dict[str, np.ndarray]:
        """:meth:`read_arrays` of bytes already read from ``rel`` (which names the file in errors)."""
        try:
            with np.load(io.BytesIO(data), allow_pickle=False) as z:
                return {k: z[k] for k in z.files}
        except (zipfile.BadZipFile, ValueError, OSError, EOFError) as exc:
            raise StoreDamaged(f"{self.uri}: {rel} is not a readable array file ({exc.__class__.__name__})") from exc
