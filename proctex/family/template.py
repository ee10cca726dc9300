"""The family's textured template as stored (:class:`Template`): its shape, parts and groups, UVs,
group textures and painted masks, with :meth:`Template.save` and :meth:`Template.load` on a family
store. The stored grouping is read back as it was painted, not analysed again."""

from __future__ import annotations

import io
import json
from pathlib import Path
from dataclasses import dataclass
from typing import Any

import numpy as np

from proctex.fileio import atomic_write
from proctex.geometry.parts import Grouping, analyse, segment
from proctex.geometry.shape import Shape
from .store import FamilyStore, StoreLayout, check_digest, digest, group_file_name


@dataclass
class Template:
    """A textured template.

    Attributes:
        shape: the template mesh; grouping: its parts and groups (:class:`proctex.geometry.parts.Grouping`).
        corner_uv: (m, 3, 2) float64 per-face corner UVs; face_group: (m,) int64 group per face.
        textures: per group an (H, W, 3) uint8 texture; labels: per group its label ("" for none),
            which names its texture file (:attr:`names`: the label, or ``group_<g>``).
        painted, observed: per group (H, W) bool masks (texels holding colour; texels the painter
            itself coloured), or None for stores written before they were kept.
        pbr: per group its PBR maps (:class:`proctex.texture.pbr.PbrMaps`, uint8 images) or None;
            None as a whole for stores written before maps were made.
    """

    shape: Shape
    grouping: Grouping
    corner_uv: np.ndarray
    face_group: np.ndarray
    textures: list[np.ndarray]
    labels: list[str]
    painted: list[np.ndarray] | None = None
    observed: list[np.ndarray] | None = None
    pbr: list[Any] | None = None

    @property
    def names(self) -> list[str]:
        """Per group its label, or ``group_<g>`` for a group without one (the GLB's material names)."""
        return [label or f"group_{g}" for g, label in enumerate(self.labels)]

    def save(self, store: FamilyStore) -> None:
        """Write the grouping, UVs, masks and group textures (PNG) into ``store`` (atomically, file
        by file). The painter's own outputs (summary, preview, textured GLB) are the paint stage's."""
        from proctex.fileio import encode_png

        store.write_json(StoreLayout.GROUPING, self.grouping.to_dict())
        store.write_arrays(StoreLayout.UV, corner_uv=self.corner_uv, face_group=self.face_group)
        if self.painted is not None:
            observed = self.observed if self.observed is not None else self.painted
            store.write_arrays(StoreLayout.PAINTED, **{f"g{k}": m for k, m in enumerate(self.painted)},
                               **{f"o{k}": m for k, m in enumerate(observed)})
        digests: dict[int, dict[str, Any]] = {}
        for g, (tex, label) in enumerate(zip(self.textures, self.labels)):
            png = encode_png(tex)
            store.write_bytes(StoreLayout.texture(g, label), png)
            digests[g] = {"sha256": digest(png)}
            maps = self.pbr[g] if self.pbr is not None else None
            if maps is not None:
                for kind, image in (("orm", maps.orm_uint8()), ("normal", maps.normal_uint8())):
                    data = encode_png(image)
                    store.write_bytes(StoreLayout.texture(g, label, kind), data)
                    digests[g][f"{kind}_sha256"] = digest(data)
                digests[g]["occlusion"] = bool(maps.occlusion)
        if store.exists(StoreLayout.PAINT):  # the painter's summary records each texture's checksum
            summary = store.read_json(StoreLayout.PAINT)
            for entry in summary.get("groups", []):
                if entry.get("group") in digests:
                    for key in ("orm_sha256", "normal_sha256", "occlusion"):
                        entry.pop(key, None)
                    entry.update(digests[entry["group"]])
            store.write_json(StoreLayout.PAINT, summary)

    @classmethod
    def load(cls, store: FamilyStore, shape: Shape, seed: int = 0) -> "Template":
        """The template stored in ``store`` on its mesh ``shape``. Stores written before the member
        maps were stored get their grouping analysed again (``seed``, as the paint stage did)."""
        from PIL import Image

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
        summary = store.read_json(StoreLayout.PAINT)
        textures, labels = [], []
        size = summary.get("texture_size") or None
        pbr: list[Any] = []

        def read(rel: str, recorded: str | None, hw: tuple[int, ...] | None) -> np.ndarray:
            png = store.read_bytes(rel)
            where = store.path(rel)
            check_digest(png, recorded, where)
            try:
                image = Image.open(io.BytesIO(png))
                image.load()
            except Exception as exc:  # PIL raises many kinds for damaged files
                raise ValueError(f"{where}: cannot read the texture ({type(exc).__name__}: {str(exc)[:200]})") from exc
            if image.mode not in ("RGB", "RGBA"):
                raise ValueError(f"{where}: a {image.mode} image; group textures are RGB")
            if hw and list(image.size[::-1]) != [int(x) for x in hw][:2]:
                raise ValueError(f"{where}: {image.size[0]}x{image.size[1]}, the family's textures are {hw[1]}x{hw[0]}")
            return np.asarray(image.convert("RGB"))

        for g in summary["groups"]:
            textures.append(read(StoreLayout.texture(g["group"], g["label"]), g.get("sha256"), size))
            labels.append(g["label"] or "")
            if g.get("orm_sha256") and g.get("normal_sha256"):  # the maps, where the paint stage made them
                from proctex.texture.pbr import PbrMaps

                hw = textures[-1].shape[:2]
                pbr.append(PbrMaps(read(StoreLayout.texture(g["group"], g["label"], "orm"), g["orm_sha256"], hw),
                                   read(StoreLayout.texture(g["group"], g["label"], "normal"), g["normal_sha256"], hw),
                                   bool(g.get("occlusion", False))))
            else:
                pbr.append(None)
        if len(textures) != len(grouping.groups):
            raise ValueError(f"{store.uri}: {len(textures)} group textures for {len(grouping.groups)} groups")
        painted = observed = None
        if store.exists(StoreLayout.PAINTED):
            arrays = store.read_arrays(StoreLayout.PAINTED)
            painted = [np.asarray(arrays[f"g{k}"], dtype=bool) for k in range(sum(n.startswith("g") for n in arrays))]
            observed = [np.asarray(arrays[f"o{k}"], dtype=bool) for k in range(len(painted))] if "o0" in arrays else painted
        return cls(shape, grouping, np.asarray(uv["corner_uv"], dtype=np.float64), np.asarray(uv["face_group"], dtype=np.int64),
                   textures, labels, painted, observed, pbr if any(m is not None for m in pbr) else None)

    def assets(self) -> Any:
        """:class:`proctex.family.assets.TemplateAssets` for transfer. Without stored masks, the texels
        each group's UV charts cover plus an 8-texel gutter count as painted and observed."""
        from .assets import prepare_template

        assets = prepare_template(self.shape, self.grouping, self.corner_uv, self.textures, self.names, pbr=self.pbr)
        if self.painted is not None:
            assets.painted, assets.observed = self.painted, self.observed
        else:
            from proctex.texture.uv import pad_seams, texel_map

            masks = []
            for ga, tex in zip(assets.groups, assets.textures):
                h, w = tex.shape[:2]
                tm = texel_map(ga.vertices, ga.faces, ga.corner_uv, h, w)
                _, mask = pad_seams(np.zeros((h, w, 1)), tm.mask, 8)
                masks.append(mask)
            assets.painted, assets.observed = masks, masks
        return assets


def write_textured(tex: Any, out: str | Path, up: str = "z", obj: bool = False, preview_size: int = 256) -> dict[str, Any]:
    """Write a painted template (:class:`proctex.texture.paint.TemplateTexture`) into the folder ``out``: the per-group PNGs, ``textured.glb``, ``preview.png`` (six views) and ``paint.json``.

    Every file is written atomically; returns the summary written to ``paint.json`` (with the
    coverage of the result and the written paths).
    """
    from proctex.geometry.preview import grid_image
    from proctex.texture.export import write_glb, write_obj
    from proctex.texture.metrics import coverage
    from proctex.texture.paint import preview_views
    from proctex.texture.render import save_png

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for g in tex.groups:
        save_png(out / group_file_name(g.group, g.label), g.uint8())
        written.append(str(out / group_file_name(g.group, g.label)))
        if g.pbr is not None:
            for kind, image in (("orm", g.pbr.orm_uint8()), ("normal", g.pbr.normal_uint8())):
                save_png(out / group_file_name(g.group, g.label, kind), image)
                written.append(str(out / group_file_name(g.group, g.label, kind)))
    names = [g.label or f"group_{g.group}" for g in tex.groups]
    textures = [g.uint8() for g in tex.groups]
    pbr = tex.pbr if any(m is not None for m in tex.pbr) else None
    shape = tex.shape
    write_glb(out / "textured.glb", shape.vertices, shape.faces, tex.uv.corner_uv, tex.uv.face_group, textures, names=names, up=up, pbr=pbr)
    written.append(str(out / "textured.glb"))
    if obj:
        written += write_obj(out / "textured.obj", shape.vertices, shape.faces, tex.uv.corner_uv, tex.uv.face_group, textures, names=names, pbr=pbr)
    views = preview_views(tex, up, preview_size)
    save_png(out / "preview.png", grid_image([views[:3], views[3:]]))
    written.append(str(out / "preview.png"))
    cov = coverage(shape.vertices, shape.faces, tex.uv.corner_uv, tex.uv.face_group, tex.painted_masks, up=up)
    summary = {**tex.summary(), "up": up, "coverage": cov.to_dict(), "files": written + [str(out / StoreLayout.PAINT_NAME)]}
    atomic_write(out / StoreLayout.PAINT_NAME, json.dumps(summary, indent=1))
    return summary
