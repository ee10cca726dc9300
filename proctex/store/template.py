"""The family's textured template as stored (:class:`Template`): its shape, parts and groups, UVs,
group textures and painted masks, with :meth:`Template.save` and :meth:`Template.load` on a family
store. The stored grouping is read back as it was painted, not analysed again."""

from __future__ import annotations

import io
import json
import os
import struct
import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from proctex.fileio import atomic_write, encode_png
from proctex.geometry.parts import Grouping, analyse, segment
from proctex.geometry.preview import grid_image
from proctex.geometry.shape import Shape
from proctex.sources.registry import source_kind
from proctex.store.config import BuildConfig
from proctex.store.layout import (
    FamilyStore,
    LookLayout,
    MAP_KINDS,
    StoreDamaged,
    StoreLayout,
    check_digest,
    digest,
    encode_arrays,
    group_file_name,
)
from proctex.store.samples import read_mesh, read_shape_record
from proctex.store.state import FamilyState, stored_config
from proctex.texture.export import glb_bytes, write_glb, write_obj
from proctex.texture.metrics import coverage
from proctex.texture.paint import preview_views
from proctex.texture.pbr import PbrMaps
from proctex.texture.render import save_png

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
PAINT_NAME = StoreLayout.PAINT_NAME
PNG_MODES = {0: "L", 2: "RGB", 3: "P", 4: "LA", 6: "RGBA"}  # IHDR colour type -> PIL's mode name


def png_size(data: bytes, where: str) -> tuple[int, int]:
    """(height, width) of an RGB or RGBA PNG from its header (nothing decoded); ``ValueError`` naming
    ``where`` for what is not one."""
    if len(data) < 33 or data[:8] != PNG_SIGNATURE or data[12:16] != b"IHDR":
        raise ValueError(f"{where}: cannot read the texture (not a PNG file)")
    w, h = struct.unpack(">II", data[16:24])
    if PNG_MODES.get(data[25]) not in ("RGB", "RGBA"):
        raise ValueError(f"{where}: a {PNG_MODES.get(data[25], f'colour type {data[25]}')} image; group textures are RGB")
    if not (0 < w <= 65536 and 0 < h <= 65536):
        raise ValueError(f"{where}: a {w}x{h} texture")
    return int(h), int(w)


def decode_png(data: bytes, where: str) -> np.ndarray:
    """(H, W, 3) uint8 of stored PNG bytes; ``ValueError`` naming ``where`` for a damaged file."""
    from PIL import Image

    try:
        image = Image.open(io.BytesIO(data))
        image.load()
    except Exception as exc:  # PIL raises many kinds for damaged files
        raise ValueError(f"{where}: cannot read the texture ({type(exc).__name__}: {str(exc)[:200]})") from exc
    if image.mode not in ("RGB", "RGBA"):
        raise ValueError(f"{where}: a {image.mode} image; group textures are RGB")
    return np.asarray(image.convert("RGB"))


class _Decoded(Sequence):
    """Per group an object made from stored PNG bytes (:meth:`_make`) when first read, then kept;
    pickled as the bytes alone (a Ray task's argument)."""

    def __init__(self, png: Sequence[Any], wheres: Sequence[str]) -> None:
        self.png = list(png)
        self.wheres = list(wheres)
        self._decoded: dict[int, Any] = {}
        self._lock = threading.Lock()

    def _make(self, i: int) -> Any:
        raise NotImplementedError

    def __len__(self) -> int:
        return len(self.png)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[k] for k in range(len(self))[i]]
        i = range(len(self))[i]  # negative indices; IndexError past the end
        with self._lock:
            if i not in self._decoded:
                self._decoded[i] = self._make(i)
            return self._decoded[i]

    @classmethod
    def of_decoded(cls, items: Sequence[Any], encode: Callable[[Any], Any], where: str = "texture"):
        """Made from decoded objects (``items``: arrays, or PbrMaps or None), each encoded once by
        ``encode`` and kept decoded: what a template painted in this process serves, the same as a
        store's."""
        out = cls([encode(x) if x is not None else None for x in items], [f"{where} {k}" for k in range(len(items))])
        out._decoded = dict(enumerate(items))
        return out

    def with_items(self, encoded: Mapping[int, Any], decoded: Mapping[int, Any] | None = None):
        """A copy with the items ``encoded`` ({i: PNG bytes, or PbrMaps of them}) replaced, the others
        shared (decoded or not); a replaced item is decoded from its new bytes when first read, or is
        ``decoded[i]`` where given (the array the bytes were encoded from): what is sampled and what
        is embedded come from one change, so the two cannot disagree."""
        out = type(self)(self.png, self.wheres)
        with self._lock:
            out._decoded = dict(self._decoded)
        for i, data in encoded.items():
            i = range(len(self))[i]
            out.png[i] = data
            out._decoded.pop(i, None)
            if decoded is not None and i in decoded:
                out._decoded[i] = decoded[i]
        return out

    def __getstate__(self) -> dict[str, Any]:
        return {"png": self.png, "wheres": self.wheres}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(state["png"], state["wheres"])


class StoredImages(_Decoded):
    """Per group an (H, W, 3) uint8 image decoded from its stored PNG bytes (:attr:`png`) when first
    read, then kept: loading a family decodes nothing it does not use, and its PNGs are served as
    they were stored, never encoded again. :meth:`hw` reads a size from the header alone."""

    def _make(self, i: int) -> np.ndarray:
        return decode_png(self.png[i], self.wheres[i])

    def hw(self, i: int) -> tuple[int, int]:
        """(height, width) of image ``i`` from its PNG header."""
        return png_size(self.png[i], self.wheres[i])


class StoredMaps(_Decoded):
    """Per group its PBR maps (:class:`proctex.texture.pbr.PbrMaps` of uint8 images, decoded from the
    stored PNGs when first read) or None; :attr:`png`: the same maps as the stored bytes."""

    def _make(self, i: int) -> Any:
        m = self.png[i]
        if m is None:
            return None
        return PbrMaps(decode_png(m.orm, self.wheres[i] + " (orm)"), decode_png(m.normal, self.wheres[i] + " (normal)"), m.occlusion)


@dataclass
class LookImages:
    """A look's stored images: per group its texture (:class:`StoredImages`), label, PBR maps
    (:class:`StoredMaps`, or None without maps) and painted / observed masks (None for stores
    written before they were kept). :meth:`read` checks each file against its recorded checksum and
    the family's texture size, decoding nothing."""

    textures: StoredImages
    labels: list[str]
    pbr: StoredMaps | None
    painted: list[np.ndarray] | None
    observed: list[np.ndarray] | None

    @classmethod
    def read(cls, store: FamilyStore, look: LookLayout) -> "LookImages":
        summary = store.read_json(look.PAINT)
        size = summary.get("texture_size") or None
        pngs, wheres, labels, maps = [], [], [], []

        def read(rel: str, recorded: str | None, hw: tuple[int, ...] | None) -> bytes:
            """The stored PNG, its checksum and header checked; decoded later, where used."""
            png = store.read_bytes(rel)
            where = store.path(rel)
            check_digest(png, recorded, where)
            h, w = png_size(png, where)
            if hw and [h, w] != [int(x) for x in hw][:2]:
                raise ValueError(f"{where}: {w}x{h}, the family's textures are {hw[1]}x{hw[0]}")
            wheres.append(where)
            return png

        for g in summary["groups"]:
            pngs.append(read(look.texture(g["group"], g["label"]), g.get("sha256"), size))
            labels.append(g["label"] or "")
            if g.get("orm_sha256") and g.get("normal_sha256"):  # the maps, where the paint stage made them
                hw = png_size(pngs[-1], wheres[-1])
                maps.append(
                    PbrMaps(
                        read(look.texture(g["group"], g["label"], "orm"), g["orm_sha256"], hw),
                        read(look.texture(g["group"], g["label"], "normal"), g["normal_sha256"], hw),
                        bool(g.get("occlusion", False)),
                    )
                )
            else:
                maps.append(None)
        textures = StoredImages(pngs, [store.path(look.texture(g["group"], g["label"])) for g in summary["groups"]])
        pbr = StoredMaps(maps, [store.path(look.texture(g["group"], g["label"], "")) for g in summary["groups"]]) if any(m is not None for m in maps) else None
        painted = observed = None
        if store.exists(look.PAINTED):
            arrays = store.read_arrays(look.PAINTED)
            painted = [np.asarray(arrays[f"g{k}"], dtype=bool) for k in range(sum(n.startswith("g") for n in arrays))]
            observed = [np.asarray(arrays[f"o{k}"], dtype=bool) for k in range(len(painted))] if "o0" in arrays else painted
        return cls(textures, labels, pbr, painted, observed)


@dataclass
class Template:
    """A textured template.

    Attributes:
        shape: the template mesh; grouping: its parts and groups (:class:`proctex.geometry.parts.Grouping`).
        corner_uv: (m, 3, 2) float64 per-face corner UVs; face_group: (m,) int64 group per face.
        textures: per group an (H, W, 3) uint8 texture (read from a store: :class:`StoredImages`,
            decoded where used); labels: per group its label ("" for none),
            which names its texture file (:attr:`names`: the label, or ``group_<g>``).
        painted, observed: per group (H, W) bool masks (texels holding colour; texels the painter
            itself coloured), or None for stores written before they were kept.
        pbr: per group its PBR maps (:class:`proctex.texture.pbr.PbrMaps`, uint8 images; read from a
            store: :class:`StoredMaps`) or None; None as a whole for stores written before maps were made.
    """

    shape: Shape
    grouping: Grouping
    corner_uv: np.ndarray
    face_group: np.ndarray
    textures: Sequence[np.ndarray]
    labels: list[str]
    painted: list[np.ndarray] | None = None
    observed: list[np.ndarray] | None = None
    pbr: Sequence[Any] | None = None

    @property
    def names(self) -> list[str]:
        """Per group its label, or ``group_<g>`` for a group without one (the GLB's material names)."""
        return [label or f"group_{g}" for g, label in enumerate(self.labels)]

    def save(self, store: FamilyStore, look: LookLayout | None = None) -> None:
        """Write the grouping, UVs, masks and group textures (PNG) into ``store`` (atomically, file
        by file): the textures and masks into ``look`` (default: the build's look, in ``template/``;
        the grouping and UVs only there). The painter's own outputs (summary, preview, textured GLB) are the paint stage's."""
        look = look or LookLayout()
        if look.built:  # another look shares the build's grouping and UVs: it writes its own folder only
            store.write_json(StoreLayout.GROUPING, self.grouping.to_dict())
            store.write_arrays(StoreLayout.UV, corner_uv=self.corner_uv, face_group=self.face_group)
        if self.painted is not None:
            observed = self.observed if self.observed is not None else self.painted
            store.write_arrays(look.PAINTED, **{f"g{k}": m for k, m in enumerate(self.painted)}, **{f"o{k}": m for k, m in enumerate(observed)})
        digests: dict[int, dict[str, Any]] = {}
        for g, label in enumerate(self.labels):
            # images read from a store are written back as their stored bytes, never encoded again
            png = self.textures.png[g] if isinstance(self.textures, StoredImages) else encode_png(self.textures[g])
            store.write_bytes(look.texture(g, label), png)
            digests[g] = {"sha256": digest(png)}
            stored = self.pbr.png[g] if isinstance(self.pbr, StoredMaps) else None
            maps = self.pbr[g] if self.pbr is not None and stored is None else stored
            if maps is not None:
                for kind in ("orm", "normal"):
                    data = getattr(stored, kind) if stored is not None else encode_png(getattr(maps, f"{kind}_uint8")())
                    store.write_bytes(look.texture(g, label, kind), data)
                    digests[g][f"{kind}_sha256"] = digest(data)
                digests[g]["occlusion"] = bool(maps.occlusion)
        if store.exists(look.PAINT):  # the painter's summary records each texture's checksum
            summary = store.read_json(look.PAINT)
            for entry in summary.get("groups", []):
                if entry.get("group") in digests:
                    for key in ("orm_sha256", "normal_sha256", "occlusion"):
                        entry.pop(key, None)
                    entry.update(digests[entry["group"]])
            store.write_json(look.PAINT, summary)

    @classmethod
    def load(cls, store: FamilyStore, shape: Shape, seed: int = 0, look: LookLayout | None = None) -> "Template":
        """The template stored in ``store`` on its mesh ``shape``, textured as ``look`` (default:
        the build's look). Stores written before the member maps were stored get their grouping
        analysed again (``seed``, as the paint stage did)."""
        look = look or LookLayout()
        grouping = None
        if store.exists(StoreLayout.GROUPING):
            try:
                grouping = Grouping.from_dict(store.read_json(StoreLayout.GROUPING), segment(shape))
            except ValueError:
                grouping = None  # an older record: analysed below
        if grouping is None:
            grouping = analyse(shape, seed=seed)
        uv = store.read_arrays(StoreLayout.UV)
        if len(uv["face_group"]) != shape.n_faces or uv["corner_uv"].shape != (shape.n_faces, 3, 2):
            raise ValueError(f"{store.uri}: template UVs do not match the template mesh")
        images = LookImages.read(store, look)
        if len(images.textures) != len(grouping.groups):
            raise ValueError(f"{store.uri}: {len(images.textures)} group textures for {len(grouping.groups)} groups")
        return cls(
            shape, grouping, np.asarray(uv["corner_uv"], dtype=np.float64), np.asarray(uv["face_group"], dtype=np.int64), images.textures, images.labels, images.painted, images.observed, images.pbr
        )


def encode_textures(tex: Any) -> tuple[list[bytes], list[Any]]:
    """The group textures of a painted template (:class:`proctex.texture.paint.TemplateTexture`) as
    PNG bytes, and per group its PBR maps as PNG bytes (:class:`proctex.texture.pbr.PbrMaps` of
    bytes) or None: each image encoded once, for the files, the GLB and the store alike. Up to two
    images are encoded at a time (zlib lets go of the GIL: a look's 18 PNGs at 512² take half the
    time on 2 cores)."""
    from concurrent.futures import ThreadPoolExecutor

    images = [g.uint8() for g in tex.groups]
    images += [img for g in tex.groups if g.pbr is not None for img in (g.pbr.orm_uint8(), g.pbr.normal_uint8())]
    with ThreadPoolExecutor(max(1, min(2, os.cpu_count() or 1))) as pool:
        encoded = iter(list(pool.map(encode_png, images)))
    pngs = [next(encoded) for _ in tex.groups]
    maps = [None if g.pbr is None else PbrMaps(next(encoded), next(encoded), g.pbr.occlusion) for g in tex.groups]
    return pngs, maps


def write_textured(tex: Any, out: str | Path, up: str = "z", obj: bool = False, preview_size: int = 256, encoded: tuple[list[bytes], list[Any]] | None = None) -> dict[str, Any]:
    """Write a painted template (:class:`proctex.texture.paint.TemplateTexture`) into the folder ``out``: the per-group PNGs, ``textured.glb``, ``preview.png`` (six views) and ``paint.json``.

    Every file is written atomically; returns the summary written to ``paint.json`` (with the
    coverage of the result and the written paths). ``encoded``: :func:`encode_textures` of ``tex``
    when the caller has it (each image is encoded once).
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    pngs, maps_png = encoded if encoded is not None else encode_textures(tex)
    written = []
    for g, png, maps in zip(tex.groups, pngs, maps_png):
        atomic_write(out / group_file_name(g.group, g.label), png)
        written.append(str(out / group_file_name(g.group, g.label)))
        if maps is not None:
            for kind in ("orm", "normal"):
                atomic_write(out / group_file_name(g.group, g.label, kind), getattr(maps, kind))
                written.append(str(out / group_file_name(g.group, g.label, kind)))
    names = [g.label or f"group_{g.group}" for g in tex.groups]
    pbr = maps_png if any(m is not None for m in maps_png) else None
    shape = tex.shape
    write_glb(out / "textured.glb", shape.vertices, shape.faces, tex.uv.corner_uv, tex.uv.face_group, pngs, names=names, up=up, pbr=pbr)
    written.append(str(out / "textured.glb"))
    if obj:
        textures = [g.uint8() for g in tex.groups]
        pbr_arrays = tex.pbr if any(m is not None for m in tex.pbr) else None
        written += write_obj(out / "textured.obj", shape.vertices, shape.faces, tex.uv.corner_uv, tex.uv.face_group, textures, names=names, pbr=pbr_arrays)
    views = preview_views(tex, up, preview_size)
    save_png(out / "preview.png", grid_image([views[:3], views[3:]]))
    written.append(str(out / "preview.png"))
    cov = coverage(shape.vertices, shape.faces, tex.uv.corner_uv, tex.uv.face_group, tex.painted_masks, up=up)
    summary = {**tex.summary(), "up": up, "coverage": cov.to_dict(), "files": written + [str(out / StoreLayout.PAINT_NAME)]}
    atomic_write(out / StoreLayout.PAINT_NAME, json.dumps(summary, indent=1))
    return summary


def load_template_shape(store: FamilyStore, config: BuildConfig | None = None, state: FamilyState | None = None) -> Shape:
    """The template shape as the template stage recorded it (``template/shape.npz``, checked against
    its digest): read, never made again, so loading a family never starts another program (Blender).
    A family built before ProcTex 0.16 has no record: a folder family's template is read from its
    mesh, a model family's made again from its parameters, unless making a shape starts another
    program (:attr:`proctex.sources.registry.SourceKind.starts_program`): then a ``ValueError`` asks
    for the template stage to run again. ``state``: the family state, when the caller has it."""
    state = state if state is not None else FamilyState.load(store)
    record = state.stage("template")
    if store.exists(StoreLayout.TEMPLATE_SHAPE):
        return read_shape_record(store, StoreLayout.TEMPLATE_SHAPE, record.get("shape"))
    if record.get("shape") is not None:
        raise StoreDamaged(f"{store.uri}: {StoreLayout.TEMPLATE_SHAPE} is missing (the template stage recorded it)")
    config = config if config is not None else stored_config(store, state)
    kind = source_kind(config.source)
    if not kind.regenerates:
        return read_mesh(store, StoreLayout.TEMPLATE_MESH)
    if kind.starts_program:
        raise ValueError(f"{store.uri}: built before ProcTex 0.16, it has no recorded template shape, and making one starts {kind.summary or kind.name}: build it again (proctex build) to record it")
    params = record.get("params")
    if not isinstance(params, dict):
        raise ValueError(f"{store.uri}: the template stage has no parameters recorded (rerun the build)")
    shape = config.procedural_model().generate(params)
    shape.source = StoreLayout.TEMPLATE_MESH
    return shape


def load_template(store: FamilyStore, config: BuildConfig | None = None, state: FamilyState | None = None, look: LookLayout | None = None) -> Template:
    """The stored :class:`Template` (its mesh regenerated for model families), textured as ``look``
    (default: the build's look); ``state``: the family state, when the caller has it (else read here)."""
    state = state if state is not None else FamilyState.load(store)
    config = config if config is not None else stored_config(store, state)
    return Template.load(store, load_template_shape(store, config, state), seed=config.seed, look=look)


class TemplateFiles:
    """The template's stored files (``template/``), read and replaced here only: each group's
    texture and PBR maps, the painted masks, the UVs and grouping, the textured GLB, and edits. An
    edit is a new template version: the files it replaces are kept first (its undo snapshot), then
    the new files are written, ``paint.json`` (the version record) last, so a reader never sees half
    an edit; :meth:`undo` puts the last version's snapshot back."""

    def __init__(self, store: FamilyStore, look: LookLayout | None = None) -> None:
        self.store = store
        self.look = look or LookLayout()
        self.summary = store.read_json(self.look.PAINT)

    @property
    def version(self) -> int:
        """The template version: the number of stored edits."""
        return len(self.summary.get("edits", []))

    @property
    def edits(self) -> list[dict[str, Any]]:
        return list(self.summary.get("edits", []))

    def group(self, group: int | str) -> dict[str, Any]:
        """The paint record of a group, by index or label; ``ValueError`` listing the groups."""
        for g in self.summary["groups"]:
            if str(g["group"]) == str(group) or (g["label"] and g["label"] == str(group)):
                return g
        names = [str(g["group"]) + (f" ({g['label']})" if g["label"] else "") for g in self.summary["groups"]]
        raise ValueError(f"unknown group {group!r}; the template's groups are: {', '.join(names)}")

    def _read(self, rel: str, recorded: str | None) -> bytes:
        """A template file, checked against the checksum its record keeps (:class:`StoreDamaged`
        naming it when it changed outside ProcTex: an edit never builds on, or records, a file
        nobody made)."""
        data = self.store.read_bytes(rel)
        check_digest(data, recorded, self.store.path(rel))
        return data

    def texture_png(self, group: int) -> bytes:
        g = self.group(group)
        return self._read(self.look.texture(int(g["group"]), g["label"]), g.get("sha256"))

    def texture(self, group: int) -> np.ndarray:
        """(H, W, 3) uint8 of a group's texture (its checksum checked)."""
        g = self.group(group)
        return decode_png(self.texture_png(group), self.store.path(self.look.texture(int(g["group"]), g["label"])))

    def map_png(self, group: int, kind: str) -> bytes | None:
        """A group's stored PBR map (``kind`` of :data:`proctex.store.layout.MAP_KINDS`, its checksum
        checked), or None."""
        g = self.group(group)
        recorded = g.get(f"{kind}_sha256")
        return self._read(self.look.texture(int(g["group"]), g["label"], kind), recorded) if recorded else None

    def corner_uv(self) -> np.ndarray:
        return np.asarray(self.store.read_arrays(StoreLayout.UV)["corner_uv"], dtype=np.float64)

    def face_group(self) -> np.ndarray:
        return np.asarray(self.store.read_arrays(StoreLayout.UV)["face_group"], dtype=np.int64)

    def painted_masks(self) -> dict[str, np.ndarray] | None:
        return dict(self.store.read_arrays(self.look.PAINTED)) if self.store.exists(self.look.PAINTED) else None

    def grouping(self, shape: Shape, seed: int = 0) -> Grouping:
        """The stored grouping on the template ``shape`` (analysed again, with ``seed``, only for a
        store written before the grouping was kept)."""
        if self.store.exists(StoreLayout.GROUPING):
            try:
                return Grouping.from_dict(self.store.read_json(StoreLayout.GROUPING), segment(shape))
            except ValueError:
                pass  # an older record
        return analyse(shape, seed=seed)

    def commit(
        self,
        group: int,
        record: dict[str, Any] | None = None,
        texture: bytes | None = None,
        maps: dict[str, bytes] | None = None,
        masks: dict[str, np.ndarray] | None = None,
        occlusion: bool | None = None,
        versioned: bool = True,
        glb: tuple[Shape, str] | None = None,
    ) -> dict[str, Any] | None:
        """A group's new files as one change (:meth:`FamilyStore.write_all`: everything lands, or
        nothing does and the error names the file). ``texture``: its PNG; ``maps``: PBR maps by kind;
        ``masks``: the painted masks of every group; ``record``: the edit, appended to the history;
        ``versioned``: a new template version, its undo snapshot (the files it replaces) written in
        the same change, the record gaining ``version`` and the texture digests ``before`` and
        ``after``; ``glb``: (template shape, up axis) to rewrite ``textured.glb`` in the change too.
        The files it builds on are checked against their checksums first. Returns the record."""
        g = self.group(group)
        gi = int(g["group"])
        current = self.texture_png(gi)
        current_maps = {kind: self.map_png(gi, kind) for kind in MAP_KINDS}
        writes: list[tuple[str, bytes]] = []
        summary = json.loads(json.dumps(self.summary))  # the new version; self.summary until it lands
        entry = next(e for e in summary["groups"] if int(e["group"]) == gi)
        if versioned and record is not None:
            version = self.version + 1
            self.store.delete(self.look.edit_snapshot(version, "").rstrip("/"))  # an undone version's snapshot
            kept = [(self.look.texture(gi, g["label"]), current)]
            kept += [(self.look.texture(gi, g["label"], kind), data) for kind, data in current_maps.items() if data is not None]
            kept += [(self.look.PAINT, self.store.read_bytes(self.look.PAINT))]
            if self.store.exists(self.look.PAINTED):
                kept += [(self.look.PAINTED, self.store.read_bytes(self.look.PAINTED))]
            writes += [(self.look.edit_snapshot(version, os.path.basename(rel)), data) for rel, data in kept]
            record = {**record, "version": version, "before": digest(current), "after": digest(texture if texture is not None else current)}
        if masks is not None:
            writes.append((self.look.PAINTED, encode_arrays(**masks)))
        new_png = current
        if texture is not None:
            writes.append((self.look.texture(gi, g["label"]), texture))
            entry["sha256"], new_png = digest(texture), texture
        for kind, data in (maps or {}).items():
            writes.append((self.look.texture(gi, g["label"], kind), data))
            entry[f"{kind}_sha256"] = digest(data)
            current_maps[kind] = data
        if occlusion is not None:
            entry["occlusion"] = bool(occlusion)
        if record is not None:
            if "prompt" in record:
                entry["prompt"] = record["prompt"]
            summary.setdefault("edits", []).append(record)
        if glb is not None:
            writes.append((self.look.GLB, self._glb(summary, {gi: (new_png, current_maps)}, *glb)))
        writes.append((self.look.PAINT, json.dumps(summary, indent=1).encode() + b"\n"))  # last: the version counts from here
        self.store.write_all(writes)
        self.summary = summary
        return record

    def undo(self, glb: tuple[Shape, str] | None = None) -> dict[str, Any]:
        """Put back the files the last version replaced, as one change (``paint.json`` last; with
        ``glb``, ``textured.glb`` rewritten in it); returns its edit record. ``ValueError`` when there
        is no edit, it was stored without its snapshot, or the snapshot is not what it recorded."""
        edits = self.edits
        if not edits:
            raise ValueError(f"{self.store.uri}: no stored edit to undo")
        last = edits[-1]
        version = int(last.get("version", len(edits)))
        folder = self.look.edit_snapshot(version, "")
        names = self.store.listdir(folder.rstrip("/"))
        if not names or PAINT_NAME not in names:
            raise ValueError(f"{self.store.uri}: edit {version} was stored without its undo (made before edits were versioned)")
        restored = {name: self.store.read_bytes(folder + name) for name in names}
        before = json.loads(restored[PAINT_NAME])
        g = next((e for e in before["groups"] if int(e["group"]) == int(last["group"])), None)
        if g is None:
            raise StoreDamaged(f"{self.store.path(folder)}: the snapshot's paint record lacks group {last['group']}")
        name = os.path.basename(self.look.texture(int(g["group"]), g["label"]))
        if name in restored:
            check_digest(restored[name], last.get("before") or g.get("sha256"), self.store.path(folder + name))
        writes = [(self.look.file(n), data) for n, data in restored.items() if n != PAINT_NAME]
        if glb is not None:
            pngs = {
                int(e["group"]): (
                    restored.get(os.path.basename(self.look.texture(int(e["group"]), e["label"]))),
                    {k: restored.get(os.path.basename(self.look.texture(int(e["group"]), e["label"], k))) for k in MAP_KINDS},
                )
                for e in before["groups"]
            }
            writes.append((self.look.GLB, self._glb(before, {k: v for k, v in pngs.items() if v[0] is not None}, *glb)))
        writes.append((self.look.PAINT, restored[PAINT_NAME]))
        self.store.write_all(writes)
        self.summary = before
        try:
            self.store.delete(folder.rstrip("/"))
        except OSError:
            pass  # a stale snapshot is deleted before its version is made again
        return last

    def _glb(self, summary: dict[str, Any], override: dict[int, tuple[bytes, dict[str, bytes | None]]], shape: Shape, up: str) -> bytes:
        """``textured.glb`` of the template version ``summary``: each group's PNG and maps as stored,
        or as ``override`` gives them (group -> (PNG, {kind: PNG or None}))."""
        uv = self.store.read_arrays(StoreLayout.UV)
        pngs, maps = [], []
        for e in summary["groups"]:
            gi = int(e["group"])
            if gi in override:
                png, m = override[gi]
                m = m if e.get("orm_sha256") else {}
            else:
                png = self.store.read_bytes(self.look.texture(gi, e["label"]))
                m = {k: self.store.read_bytes(self.look.texture(gi, e["label"], k)) for k in MAP_KINDS} if e.get("orm_sha256") else {}
            pngs.append(png)
            maps.append(PbrMaps(m["orm"], m["normal"], bool(e.get("occlusion"))) if m.get("orm") and m.get("normal") else None)
        names = [e["label"] or f"group_{e['group']}" for e in summary["groups"]]
        return glb_bytes(shape.vertices, shape.faces, uv["corner_uv"], uv["face_group"], pngs, names=names, up=up, pbr=maps if any(m is not None for m in maps) else None)

    def write_glb(self, shape: Shape, up: str) -> None:
        """Rewrite ``template/textured.glb`` from the template ``shape``, the UVs, the group PNGs and
        PBR maps as stored (nothing encoded again)."""
        self.store.write_bytes(self.look.GLB, self._glb(self.summary, {}, shape, up))
