"""Looks from photos, measured (issue 53, item 4): time, seams and repeats on a built family.

On a painted family (``--family STORE``: the stages sample, template and paint are enough) this
script makes two photos in code (a woven fabric and a wood grain; nothing is downloaded), then:

- **time**: a prompt look and a photo look (``--part`` takes the wood, the fabric covers the rest),
  both through :func:`proctex.looks.add_look` as ``proctex look add`` runs it, ``--repeats``
  times each, medians;
- **seams**: the photo look rendered in the six canonical views (albedo, no light): the mean colour
  step between neighbouring pixels of one group whose faces lie in *different* UV charts, over the
  step between neighbouring pixels in the same chart (1: no seam shows), and the same at matched
  distances on the surface (``ratio_matched``: seams lie where the surface bends, seen at a slant).
  Beside it the wrong way, the same photo synthesised per chart in UV space, which a seam-aware
  metric must call worse, and the control, the synthesis evaluated at each pixel's own surface
  point (no atlas: what is left is the atlas's sampling);
- **repeats**: the highest normalised autocorrelation away from zero shift (beyond 24 texels) of
  the largest group's texture over its charts (masked), painted from a stone photo made in code
  (no period of its own) spanning a tenth of the part: synthesised, and tiled on the surface in the
  same frame (the wrong way: periodic).

    .venv/bin/python tests/bench/bench_photolooks.py --family out/sofa --part legs --repeats 3

Prints a JSON report (and writes it with ``--out``).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from proctex.looks import add_look, remove_look  # noqa: E402
from proctex.store.layout import FamilyStore, StoreLayout  # noqa: E402
from proctex.store.looks import new_look_paint  # noqa: E402
from proctex.store.state import FamilyState  # noqa: E402
from proctex.texture import exemplar as E  # noqa: E402


def fabric(size: int = 256, seed: int = 0) -> np.ndarray:
    """A plain weave made in code: warp and weft threads over and under, with slub noise; (size, size, 3)."""
    r = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size].astype(float)
    period = 6.0
    warp = 0.5 + 0.5 * np.cos(2 * np.pi * x / period)
    weft = 0.5 + 0.5 * np.cos(2 * np.pi * y / period)
    over = (np.floor(x / period) + np.floor(y / period)) % 2
    thread = np.where(over > 0, warp * 0.8 + 0.2, weft * 0.8 + 0.2)
    from scipy.ndimage import gaussian_filter

    slub = gaussian_filter(r.standard_normal((size, size)), 6.0)
    shade = np.clip(0.35 + 0.45 * thread + 1.5 * slub, 0, 1)
    return np.clip(shade[..., None] * np.array([0.75, 0.32, 0.28]) + 0.05, 0, 1).astype(np.float32)


def wood(size: int = 256, seed: int = 1) -> np.ndarray:
    """A wood grain made in code: growth rings seen from the side, bent by smooth noise; (size, size, 3)."""
    from scipy.ndimage import gaussian_filter

    r = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size].astype(float)
    bend = gaussian_filter(r.standard_normal((size, size)), 16.0) * 120.0
    rings = 0.5 + 0.5 * np.sin(2 * np.pi * (y + bend) / 14.0)
    fine = gaussian_filter(r.standard_normal((size, size)), (0.6, 5.0)) * 0.8
    t = np.clip(0.55 * rings + 0.25 + fine, 0, 1)
    light, dark = np.array([0.72, 0.52, 0.32]), np.array([0.36, 0.21, 0.11])
    return (dark + (light - dark) * t[..., None]).astype(np.float32)


def stone(size: int = 256, seed: int = 2) -> np.ndarray:
    """A stone made in code, with no period of its own: mottled grains at three scales and a few
    veins; (size, size, 3). The repeats are measured on it (a woven photo repeats by itself)."""
    from scipy.ndimage import gaussian_filter

    r = np.random.default_rng(seed)
    t = sum(gaussian_filter(r.standard_normal((size, size)), s) * s**0.5 for s in (1.0, 4.0, 16.0))
    veins = np.abs(gaussian_filter(r.standard_normal((size, size)), 10.0))
    t = (t - t.mean()) / t.std() * 0.12 + 0.55 - 2.0 * np.clip(0.02 - veins, 0, None) * 10
    return np.clip(t[..., None] * np.array([0.95, 0.92, 0.86]), 0, 1).astype(np.float32)


def chart_ids(faces: np.ndarray, corner_uv: np.ndarray) -> np.ndarray:
    """(m,) UV chart of each face: faces joined across an edge whose two UVs agree on both sides."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    m = len(faces)
    keys = {}
    rows, cols = [], []
    q = np.round(np.asarray(corner_uv, dtype=np.float64) * 2**20).astype(np.int64)
    for f in range(m):
        for k in range(3):
            a, b = int(faces[f, k]), int(faces[f, (k + 1) % 3])
            ua, ub = tuple(q[f, k]), tuple(q[f, (k + 1) % 3])
            key = (a, b, ua, ub) if a < b else (b, a, ub, ua)
            other = keys.get(key)
            if other is not None:
                rows.append(f)
                cols.append(other)
            else:
                keys[key] = f
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(m, m))
    return connected_components(graph, directed=False)[1]


def seam_ratio(views: list, albedos: list[np.ndarray], charts: np.ndarray, face_group: np.ndarray, crease: float | None = None, bins: int = 10) -> dict[str, float]:
    """Mean colour step (RGB, 0-1) between neighbouring pixels of one group across UV charts over the
    step inside one chart, over all views (neighbours on the surface only: not across an occluding
    edge; with ``crease``, also not across a crease sharper than that many degrees); with both means
    and the pair counts.

    ``ratio_matched`` compares pairs at the same distance on the surface: charts are cut where the
    surface bends, which the canonical views see at a slant, so neighbouring pixels across a seam
    lie further apart on the surface (1.5-3 footprints against about 1 inside) and differ more for
    any texture that varies. The across pairs' distances are cut into ``bins`` deciles, and the mean
    across step over the mean inside step is taken over the deciles that hold both (each decile
    weighing alike): 1 where a seam shows nothing the distance does not explain."""
    across, inside, gap_a, gap_i = [], [], [], []
    for b, a in zip(views, albedos):
        f = b.face
        for axis in (0, 1):
            sl1 = (slice(None, -1), slice(None)) if axis == 0 else (slice(None), slice(None, -1))
            sl2 = (slice(1, None), slice(None)) if axis == 0 else (slice(None), slice(1, None))
            fa, fb = f[sl1], f[sl2]
            ok = (fa >= 0) & (fb >= 0)
            ok &= face_group[np.maximum(fa, 0)] == face_group[np.maximum(fb, 0)]
            # neighbours on the surface, not across an occluding edge: their points no further apart
            # than 3 pixel footprints (the median gap between neighbours on one face)
            gap = np.linalg.norm(b.points[sl1] - b.points[sl2], axis=-1)
            footprint = np.median(gap[ok & (fa == fb)]) if (ok & (fa == fb)).any() else np.inf
            ok &= gap < 3.0 * footprint
            if crease is not None:  # only where the surface is smooth: the two faces' normals within ``crease`` degrees
                cos = np.einsum("ijk,ijk->ij", b.normal[sl1], b.normal[sl2])
                ok &= cos > np.cos(np.radians(crease))
            step = np.linalg.norm(a[sl1] - a[sl2], axis=-1)
            same = charts[np.maximum(fa, 0)] == charts[np.maximum(fb, 0)]
            across.append(step[ok & ~same])
            inside.append(step[ok & same])
            gap_a.append(gap[ok & ~same] / footprint)
            gap_i.append(gap[ok & same] / footprint)
    across_v, inside_v = np.concatenate(across), np.concatenate(inside)
    ga, gi = np.concatenate(gap_a), np.concatenate(gap_i)
    matched = float("nan")
    if len(across_v) >= bins:
        edges = np.quantile(ga, np.linspace(0.0, 1.0, bins + 1))
        ka, ki = np.clip(np.searchsorted(edges, ga, side="right") - 1, 0, bins - 1), np.clip(np.searchsorted(edges, gi, side="right") - 1, 0, bins - 1)
        ki = np.where((gi >= edges[0]) & (gi <= edges[-1]), ki, -1)
        pairs = [(across_v[ka == k].mean(), inside_v[ki == k].mean()) for k in range(bins) if (ka == k).any() and (ki == k).any()]
        if pairs:
            matched = float(np.mean([p[0] for p in pairs]) / max(np.mean([p[1] for p in pairs]), 1e-12))
    return {
        "across": float(across_v.mean()) if len(across_v) else float("nan"),
        "inside": float(inside_v.mean()),
        "ratio": float(across_v.mean() / max(inside_v.mean(), 1e-12)) if len(across_v) else float("nan"),
        "ratio_matched": matched,
        "pairs_across": int(len(across_v)),
        "pairs_inside": int(len(inside_v)),
        "across_gap_median": float(np.median(ga)) if len(ga) else float("nan"),
        "inside_gap_median": float(np.median(gi)),
    }


def repeat_peak(image: np.ndarray, mask: np.ndarray, exclude: int = 24) -> float:
    """Highest normalised autocorrelation of ``image``'s luminance over ``mask`` away from zero shift
    (beyond ``exclude`` texels), where the shifted masks overlap in at least a fifth of the mask."""
    lum = (image[..., :3] @ np.array([0.2126, 0.7152, 0.0722])) * mask
    lum = np.where(mask, lum - lum[mask].mean(), 0.0)
    H, W = lum.shape
    pad = (2 * H, 2 * W)
    F, M = np.fft.rfft2(lum, pad), np.fft.rfft2(mask.astype(float), pad)
    num = np.fft.irfft2(F * np.conj(F), pad)
    cnt = np.fft.irfft2(M * np.conj(M), pad)
    var = num[0, 0] / max(cnt[0, 0], 1.0)
    ac = np.where(cnt > 0.2 * cnt[0, 0], num / np.maximum(cnt, 1.0) / max(var, 1e-12), 0.0)
    ac = np.fft.fftshift(ac)
    cy, cx = ac.shape[0] // 2, ac.shape[1] // 2
    yy, xx = np.ogrid[: ac.shape[0], : ac.shape[1]]
    ac[(yy - cy) ** 2 + (xx - cx) ** 2 < exclude**2] = 0.0
    return float(ac.max())


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--family", required=True)
    ap.add_argument("--part", default="legs", help="the part word the wood goes on (the fabric covers the rest)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out")
    args = ap.parse_args(argv)
    store = FamilyStore(args.family)
    config = FamilyState.load(store).build_config(store.uri)
    work = Path(args.out).parent if args.out else Path("out/bench_photolooks")
    work.mkdir(parents=True, exist_ok=True)
    photos = {"fabric": E.Photo(fabric(), "fabric.png"), "wood": E.Photo(wood(), "wood.png")}
    for name, p in photos.items():
        (work / f"{name}.png").write_bytes(p.png())
    images = {args.part: {"file": str(work / "wood.png")}, "*": {"file": str(work / "fabric.png"), "under_prompt": False}}
    by_key = {args.part: photos["wood"], "*": photos["fabric"]}
    quiet = lambda *_: None  # noqa: E731
    times: dict[str, list[float]] = {"prompt": [], "photos": []}
    for _ in range(args.repeats):
        for kind in ("prompt", "photos"):
            paint = new_look_paint(config.paint, "a red velvet sofa with dark walnut legs" if kind == "prompt" else None, images=images if kind == "photos" else None)
            t0 = time.perf_counter()
            add_look(store, f"bench-{kind}", paint, force=True, log=quiet, photos=by_key if kind == "photos" else None)
            times[kind].append(time.perf_counter() - t0)
    report: dict = {"family": store.uri, "texture_size": config.paint.texture_size, "seconds": {k: statistics.median(v) for k, v in times.items()}, "runs": times}
    report["ratio_photo_to_prompt"] = report["seconds"]["photos"] / report["seconds"]["prompt"]

    # seams and repeats on the photo look
    from proctex.store.template import TemplateFiles, load_template_shape
    from proctex.texture.render import Tracer, canonical_cameras, bounding_sphere, render_buffers, textured_albedo

    state = FamilyState.load(store)
    shape = load_template_shape(store, config, state)
    files = TemplateFiles(store, StoreLayout.look("bench-photos"))
    corner_uv, face_group = files.corner_uv(), files.face_group()
    n_groups = int(face_group.max()) + 1
    textures = [files.texture(g) for g in range(n_groups)]
    charts = chart_ids(shape.faces, corner_uv)
    tracer = Tracer(shape.vertices, shape.faces)
    centre, radius = bounding_sphere(shape.vertices)
    views = [render_buffers(tracer, cam) for cam in canonical_cameras(centre, radius, config.up_axis(), size=512)]

    def albedos(texs):
        return [textured_albedo(b, corner_uv, face_group, texs) for b in views]

    report["seams"] = {"look": seam_ratio(views, albedos(textures), charts, face_group)}
    prompt_files = TemplateFiles(store, StoreLayout.look("bench-prompt"))  # the solid prompt look: continuous by construction
    report["seams"]["prompt_look"] = seam_ratio(views, albedos([prompt_files.texture(g) for g in range(n_groups)]), charts, face_group)
    # the wrong way: each group's photo synthesised in its UV space (per chart, blind to the surface)
    grouping = files.grouping(shape, seed=config.seed)
    from proctex.texture.paint import group_texels, resolve_photos
    from proctex.texture.uv import pad_seams

    layers = {k: E.PhotoLayer(v) for k, v in by_key.items()}
    per_group = resolve_photos(grouping, config.paint.prompt, layers, shape, config.up_axis(), {}, set())
    size = config.paint.texture_size
    texels = group_texels(shape, grouping, files_uv(files, shape, grouping, size), size)
    uv_space = []
    painter = E.PhotoPainter(_Plain(), per_group, seed=config.seed, texture_size=size).bind(shape, grouping, config.up_axis())
    c0, r0 = painter._frame
    for g, tx in zip(grouping.groups, texels):
        b = painter._bound[g.index]
        uv = np.stack([(tx.ij[:, 1] + 0.5), (tx.ij[:, 0] + 0.5)], axis=1) * (b.ex.shape[1] * 2.0 / size)
        img = np.zeros((size, size, 3), np.float32)
        img[tx.ij[:, 0], tx.ij[:, 1]] = E.synthesise(b.ex, uv, seed=1)
        uv_space.append(pad_seams(img, tx.mask, 8)[0])
    report["seams"]["per_chart_uv_synthesis"] = seam_ratio(views, albedos(uv_space), charts, face_group)
    # the control: the same synthesis evaluated at each pixel's own surface point (no atlas), on the
    # pixels of each group's representative (the other members read its texture through their maps)
    direct = E.PhotoPainter(_Plain(), per_group, seed=config.seed, texture_size=size).bind(shape, grouping, config.up_axis())
    report["seams"]["synthesis_at_the_pixels"] = seam_ratio(*direct_views(views, shape, grouping, direct), charts, face_group)
    # repeats: the largest group painted from a stone photo (no period of its own) at a tenth of the
    # part's longest side (so the part holds many photo widths), synthesised and tiled
    big = max(range(len(texels)), key=lambda g: len(texels[g].face))
    rock = E.Photo(stone(), "stone.png")
    probe = E.PhotoPainter(_Plain(), {big: E.PhotoLayer(rock)}, seed=config.seed, texture_size=size).bind(shape, grouping, config.up_axis())
    b = probe._bound[big]
    probe = E.PhotoPainter(_Plain(), {big: E.PhotoLayer(rock, scale=b.scale / 5.0)}, seed=config.seed, texture_size=size).bind(shape, grouping, config.up_axis())
    b, tx = probe._bound[big], texels[big]
    from proctex.texture.paint import blend_normals, shape_frame

    c0, r0 = shape_frame(shape)
    normals = blend_normals(shape, grouping.parts[grouping.groups[big].representative].faces, tx)
    synth = np.zeros((size, size, 3), np.float32)
    synth[tx.ij[:, 0], tx.ij[:, 1]] = probe.paint((tx.points - c0) / r0, normals, group=big)
    local = (tx.points - b.centre) @ b.axes.T / b.ex.pixel  # tiled on the surface: the same frame, the photo repeated
    cols = np.empty((len(tx.face), 3), np.float32)
    for k, (i, j) in enumerate(((1, 2), (0, 2), (0, 1))):  # the dominant projection, not blended
        sel = np.argmax(np.abs(normals @ b.axes.T), axis=1) == k
        if sel.any():
            cols[sel] = E.tiled(b.ex, local[sel][:, [i, j]])
    tiled = np.zeros((size, size, 3), np.float32)
    tiled[tx.ij[:, 0], tx.ij[:, 1]] = cols
    report["repeats"] = {"group": big, "exclude_texels": 24, "photo_widths_on_the_part": 10.0, "synthesised": repeat_peak(synth, tx.mask), "tiled": repeat_peak(tiled, tx.mask)}
    for kind in ("prompt", "photos"):
        remove_look(store, f"bench-{kind}")
    text = json.dumps(report, indent=1)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")
    return report


def direct_views(views: list, shape, grouping, painter) -> tuple[list, list[np.ndarray]]:
    """The views with only the groups' representatives' pixels kept (others: face -1), and per view
    the painter's colours at those pixels' surface points, with the smooth normal field its colour
    follows in a look (:func:`proctex.texture.paint.blend_normals`): the synthesis with no atlas."""
    from dataclasses import replace
    from types import SimpleNamespace

    from proctex.texture.paint import blend_normals, shape_frame

    c0, r0 = shape_frame(shape)
    owner = np.full(len(shape.faces), -1)  # representative faces: their group
    local = np.zeros(len(shape.faces), np.int64)  # ... and their index among the representative's faces
    for g in grouping.groups:
        faces = np.asarray(grouping.parts[g.representative].faces)
        owner[faces], local[faces] = g.index, np.arange(len(faces))
    kept, colours = [], []
    for b in views:
        face = np.where((b.face >= 0) & (owner[np.maximum(b.face, 0)] >= 0), b.face, -1)
        img = np.zeros(face.shape + (3,), np.float32)
        for g in grouping.groups:
            sel = (face >= 0) & (owner[np.maximum(face, 0)] == g.index)
            if not sel.any():
                continue
            at = SimpleNamespace(face=local[face[sel]], bary=b.bary[sel], normals=b.normal[sel])  # the pixels as the representative's texels
            normals = blend_normals(shape, grouping.parts[g.representative].faces, at)
            img[sel] = painter.paint((b.points[sel] - c0) / r0, normals, group=g.index)
        kept.append(replace(b, face=face))
        colours.append(img)
    return kept, colours


def files_uv(files, shape, grouping, size):
    from proctex.looks import stored_uv

    return stored_uv(files, shape, grouping, size)


class _Plain:
    """The prompt painter's place when every group has a photo (never asked to paint)."""

    def bind(self, *a, **k):
        return self

    def notes(self):
        return []


if __name__ == "__main__":
    main()
