"""The main job's outputs: a sweep of unseen parameter settings of a built family, transferred and
rendered into a contact sheet, a turntable GIF of the sweep, a GLB per variant and an HTML report.

Pure functions plus :func:`finish_demo`, which runs them over a built family store. The build itself
is the caller's (``proctex.build.pipeline.build`` in one process, ``workflows.build.build_on_ray`` on Ray);
``proctex`` never imports Ray.
"""

from __future__ import annotations

import html
import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from proctex.build.pipeline import build
from proctex.serve.service import FamilyService
from proctex.store.config import BuildConfig, PRESETS, merge, resolved_settings, sections
from proctex.store.layout import FamilyStore, StoreLayout
from proctex.store.state import FamilyState, stored_config
from proctex.texture.render import Tracer, bounding_sphere, orbit_camera, render_textured, save_gif, save_png
from proctex.transfer.apply import shape_to_glb, transfer

from .fileio import atomic_write
from .params import ParamSpace, ParamSpec
from .progress import Progress

#: The demo's default family: the built-in sofa, painted with one design that has to follow every
#: cushion, arm and leg across the sweep.
DEMO_MODEL = "sofa"
DEMO_PROMPT = "a patchwork bohemian sofa"


def demo_config(model: str = DEMO_MODEL, prompt: str = DEMO_PROMPT, seed: int = 0, n_train: int = 10, n_test: int = 3, group_prompts: dict[str, str] | None = None) -> dict[str, Any]:
    """The demo's build config as sections: the ``demo`` preset (:data:`proctex.store.config.PRESETS`)
    with this model, prompt, seed and shape counts. A few minutes on 2 cores."""
    return merge(sections(PRESETS["demo"]), {"seed": seed, "source": {"model": model, "n_train": n_train, "n_test": n_test}, "paint": {"prompt": prompt, "group_prompts": dict(group_prompts or {})}})


# ------------------------------------------------------------------------------------------ sweep
@dataclass
class SweepRow:
    """One row of the contact sheet: ``settings`` (full parameter dicts) varying ``name`` (or every
    parameter for the row of random unseen settings, ``name == "random"``)."""

    name: str
    settings: list[dict[str, Any]]


def row_values(spec: ParamSpec, n: int) -> list[Any]:
    """``n`` values spanning a parameter: evenly spaced over a range (integers: distinct, at most
    every integer), every option of a choice."""
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    if spec.kind == "choice":
        return list(spec.options)
    if spec.kind == "integer":
        lo, hi = int(spec.low), int(spec.high)
        if hi - lo + 1 <= n:
            return list(range(lo, hi + 1))
        return sorted({int(round(x)) for x in np.linspace(lo, hi, n)})
    if n == 1:
        return [float(spec.default)]
    return [float(x) for x in np.linspace(spec.low, spec.high, n)]


def parameter_effects(space: ParamSpace, base: dict[str, Any], generate: Callable[[dict[str, Any]], Any]) -> dict[str, float]:
    """How visibly each parameter changes the shape, from ``base``: a topology change (the face count
    differs between the parameter's extremes) scores 10 + the relative change of the bounding-box
    extents; otherwise just the latter. ``generate(params) -> Shape``."""
    ref = generate(base)
    ext = np.ptp(ref.vertices, axis=0)
    scale = float(np.linalg.norm(ext)) or 1.0
    scores: dict[str, float] = {}
    for spec in space.specs:
        vals = row_values(spec, 2)
        shapes = [generate({**base, spec.name: v}) for v in (vals[0], vals[-1])]
        change = float(np.linalg.norm(np.ptp(shapes[0].vertices, axis=0) - np.ptp(shapes[1].vertices, axis=0))) / scale
        topo = 10.0 if len({s.n_faces for s in shapes + [ref]}) > 1 else 0.0
        scores[spec.name] = topo + change
    return scores


def sweep_settings(
    space: ParamSpace, base: dict[str, Any], effects: dict[str, float], rows: int = 3, per_row: int = 5, names: Sequence[str] | None = None, random_row: bool = True, seed: int = 0
) -> list[SweepRow]:
    """Rows of parameter settings around ``base``: the ``rows`` parameters with the largest
    ``effects`` (or ``names``), each swept over its range with the others at ``base``, then a row of
    ``per_row`` random (Latin-hypercube) settings of every parameter, seeded."""
    if rows < 0 or per_row < 1:
        raise ValueError(f"need rows >= 0 and per_row >= 1, got {rows}, {per_row}")
    base = space.validate(base)
    if names is None:
        names = sorted(space.names, key=lambda n: (-effects.get(n, 0.0), space.names.index(n)))[:rows]
    out = []
    for name in names:
        spec = space[name]  # KeyError for unknown names
        out.append(SweepRow(name, [space.validate({**base, name: v}) for v in row_values(spec, per_row)]))
    if random_row and len(space):
        out.append(SweepRow("random", [space.validate(p) for p in space.sample(per_row, seed=seed + 7919, method="lhs")]))
    return out


def turntable_path(space: ParamSpace, base: dict[str, Any], names: Sequence[str], frames: int) -> list[dict[str, Any]]:
    """``frames`` settings for a turntable of the sweep: parameter ``names[k]`` follows a triangle wave
    over its range (low → high → low), phase-shifted per parameter; integers round, choices step."""
    if frames < 1:
        raise ValueError(f"frames must be >= 1, got {frames}")
    base = space.validate(base)
    out = []
    for f in range(frames):
        p = dict(base)
        for k, name in enumerate(names):
            spec = space[name]
            t = (f / frames + k / max(len(names), 1) / 2) % 1.0
            u = 1.0 - abs(2.0 * t - 1.0)  # 0 -> 1 -> 0
            if spec.kind == "choice":
                p[name] = spec.options[min(int(u * len(spec.options)), len(spec.options) - 1)]
            elif spec.kind == "integer":
                p[name] = int(round(spec.low + u * (spec.high - spec.low)))
            else:
                p[name] = float(spec.low + u * (spec.high - spec.low))
        out.append(space.validate(p))
    return out


def caption(params: dict[str, Any], varied: str | None, max_lines: int = 6, shown: Sequence[str] | None = None) -> list[str]:
    """Caption lines of a variant: the varied parameter, or every parameter (random row; only those
    in ``shown`` when given, e.g. the ones that matter there), at most ``max_lines`` of them and a
    "+k more" line."""

    def fmt(v: Any) -> str:
        return f"{v:.3g}" if isinstance(v, float) else str(v)

    keys = [varied] if varied else [k for k in params if shown is None or k in shown]
    lines = [f"{k} = {fmt(params[k])}" for k in keys]
    return lines if len(lines) <= max_lines else lines[: max_lines - 1] + [f"+{len(lines) - max_lines + 1} more"]


# ------------------------------------------------------------------------------------------ images
def _font(size: int):
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1
        return ImageFont.load_default()


def crop_to_content(images: Sequence[np.ndarray], background: int = 255, margin: int = 6) -> list[np.ndarray]:
    """Crop equally sized (H, W, 3) uint8 images to the union of their non-background boxes (plus
    ``margin`` pixels), the same box for all, so images from one camera stay comparable."""
    if not images:
        return []
    fg = np.zeros(images[0].shape[:2], dtype=bool)
    for im in images:
        if im.shape[:2] != fg.shape:
            raise ValueError("crop_to_content needs images of one size")
        fg |= (np.asarray(im) != background).any(axis=2)
    if not fg.any():
        return [np.asarray(im) for im in images]
    rows, cols = np.flatnonzero(fg.any(axis=1)), np.flatnonzero(fg.any(axis=0))
    r0, r1 = max(rows[0] - margin, 0), min(rows[-1] + margin + 1, fg.shape[0])
    c0, c1 = max(cols[0] - margin, 0), min(cols[-1] + margin + 1, fg.shape[1])
    return [np.ascontiguousarray(np.asarray(im)[r0:r1, c0:c1]) for im in images]


def contact_sheet(rows: list[list[np.ndarray]], captions: list[list[list[str]]], row_titles: list[str], title: str = "", pad: int = 8) -> np.ndarray:
    """(H, W, 3) uint8 sheet: rows of equally sized images, each with caption lines below it, a
    title line per row and an optional sheet title."""
    from PIL import Image, ImageDraw

    if not rows or not all(rows):
        raise ValueError("contact_sheet needs at least one non-empty row of images")
    h, w = rows[0][0].shape[:2]
    font, big = _font(max(10, w // 18)), _font(max(12, w // 12))
    line = max(10, w // 18) + 4
    head = (max(12, w // 12) + 2 * pad) if title else pad
    row_head = line + 2 * pad
    cell_h = [h + max(len(c) for c in caps) * line + pad for caps in captions]  # per row: its caption lines
    cols = max(len(r) for r in rows)
    W = cols * (w + pad) + pad
    H = head + len(rows) * row_head + sum(cell_h) + pad
    sheet = Image.new("RGB", (W, H), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    if title:
        draw.text((pad, pad), title, fill=(20, 20, 20), font=big)
    y = head
    for r, (row, caps, rt) in enumerate(zip(rows, captions, row_titles)):
        draw.text((pad, y + pad), rt, fill=(60, 60, 60), font=font)
        y += row_head
        for c, (img, cap) in enumerate(zip(row, caps)):
            x = pad + c * (w + pad)
            sheet.paste(Image.fromarray(np.asarray(img, dtype=np.uint8)), (x, y))
            for k, text in enumerate(cap):
                draw.text((x + 2, y + h + 2 + k * line), text, fill=(30, 30, 30), font=font)
        y += cell_h[r]
    return np.asarray(sheet)


# ------------------------------------------------------------------------------------------ report
def _table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    th = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><thead><tr>{th}</tr></thead><tbody>{body}</tbody></table>"


def _num(x: Any, nd: int = 4) -> str:
    return "–" if x is None else (f"{x:.{nd}f}" if isinstance(x, float) else html.escape(str(x)))


def report_html(summary: dict[str, Any]) -> str:
    """The HTML report of a demo run from its ``summary`` (what :func:`finish_demo` writes to
    ``demo.json``). Links are relative to the output folder; user text is escaped."""
    e = html.escape
    s = summary
    groups = _table(
        ["group", "label", "prompt", "texture", "network"],
        [
            [
                str(g["group"]),
                e(g["label"] or "–"),
                e(g["prompt"] or ""),
                f'<a href="{e(g["texture"])}"><img class="tex" src="{e(g["texture"])}" alt="group {g["group"]} texture"></a>',
                e(g["network"]),
            ]
            for g in s["groups"]
        ],
    )
    stage_rows = [[e(k), f"{v:.1f}"] for k, v in s["stage_seconds"].items()]
    stages = _table(["stage", "seconds"], stage_rows + [["<b>total wall time</b>", f"<b>{s['total_seconds']:.1f}</b>"]])
    metrics = "<p>No evaluation (fewer than two test shapes).</p>"
    if s.get("metrics"):
        mrows = []
        for name, m in s["metrics"]["methods"].items():
            pgt, gt = m.get("pgt_error") or {}, m.get("gt_error") or {}
            ms = "–" if m.get("seconds_per_shape") is None else f"{1000 * m['seconds_per_shape']:.0f}"
            mrows.append(
                [
                    e(name),
                    _num(m.get("tracked_point_variance")),
                    _num(m.get("tracked_point_variance_realtime")),
                    _num(gt.get("mean")),
                    _num(gt.get("max")),
                    _num(pgt.get("mean")),
                    _num(pgt.get("max")),
                    _num(m.get("coverage")),
                    f"{m.get('mapped_share', 0.0):.0%}" if name.startswith("corrnet") else "–",
                    ms,
                ]
            )
        metrics = (
            f"<p>{s['metrics']['shapes']} unseen test shapes; points tracked by {e(str(s['metrics'].get('tracker')))} "
            f"(never by the method's own map); errors in the template part's normalised frame, max over all points.</p>"
            + _table(["method", "tracked-point variance (baked)", "(real-time)", "GT error mean", "GT max", "pseudo-GT error mean", "max", "coverage", "networks on parts", "ms per shape"], mrows)
        )
    variants = _table(
        ["row", "parameters", "transfer ms", "faces", "GLB"],
        [
            [e(v["row"]), "<code>" + e(json.dumps(v["params"])) + "</code>", f"{1000 * v['seconds']:.0f}", str(v["faces"]), f'<a href="{e(v["glb"])}">{e(Path(v["glb"]).name)}</a>']
            for v in s["variants"]
        ],
    )
    notes = "".join(f"<li>{e(n)}</li>" for n in s.get("notes", [])) or "<li>none</li>"
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>ProcTex demo: {e(s["model"])}</title>
<style>
body {{ font: 14px/1.45 system-ui, sans-serif; margin: 2em auto; max-width: 1200px; color: #222; }}
table {{ border-collapse: collapse; margin: .5em 0 1.5em; }} td, th {{ border: 1px solid #ccc; padding: 4px 8px; vertical-align: middle; }}
th {{ background: #f3f3f3; }} img.tex {{ width: 96px; height: 96px; image-rendering: auto; }} img.wide {{ max-width: 100%; }}
code {{ font-size: 12px; }}
</style></head><body>
<h1>ProcTex demo: <i>{e(s["model"])}</i></h1>
<p>Prompt: <b>{e(s["prompt"])}</b>. Family store: <code>{e(s["family"])}</code> ({s["n_train"]} training shapes, {s["n_test"]} test shapes,
seed {s["seed"]}, built {"on Ray" if s["ray"] else "in one process"}). {len(s["variants"])} unseen variants transferred,
median {1000 * s["transfer_median_seconds"]:.0f} ms each.</p>
<h2>Contact sheet</h2>
<p>Every row sweeps one parameter from the template's setting (the last row: random unseen settings); one camera for all.</p>
<img class="wide" src="{e(s["contact_sheet"])}" alt="contact sheet">
<h2>Turntable of the sweep</h2>
<img src="{e(s["turntable"])}" alt="turntable">
<h2>Groups and their textures</h2>
{groups}
<h2>Metrics</h2>
{metrics}
<h2>Timings</h2>
{stages}
<h2>Variants</h2>
{variants}
<h2>Notes</h2><ul>{notes}</ul>
<p>Open the family in the studio: <code>proctex serve {e(s["serve_root"])}</code>, then <code>http://127.0.0.1:8000/</code>.</p>
</body></html>
"""


def render_sheet(
    sweep: list[SweepRow],
    rendered: list[tuple[Any, Any]],
    textures: list[np.ndarray],
    up: str,
    size: int,
    title: str = "",
    quiet: bool = False,
    maps: list | None = None,
    space: ParamSpace | None = None,
) -> np.ndarray:
    """The contact sheet of transferred variants ``rendered`` [(Shape, TransferResult)], in the order
    of ``sweep``'s rows: one camera fitted to every variant (sizes compare truthfully), crops shared.
    ``maps``: the template's PBR maps per texture (None: colour only), lit physically. ``space``:
    random settings are captioned with the parameters that matter there (:meth:`ParamSpace.active`)."""
    center, radius = bounding_sphere(np.concatenate([s.vertices for s, _ in rendered]))
    cam = orbit_camera(center, radius, up, -35.0, 22.0, size, fov_deg=32.0)
    bar = Progress("render", len(rendered), quiet=quiet)
    images = []
    for shape, result in rendered:
        images.append(
            render_textured(
                shape.vertices,
                shape.faces,
                result.corner_uv,
                result.face_group,
                list(textures) + list(result.new_textures),
                cam,
                maps=None if maps is None else list(maps) + [None] * len(result.new_textures),
            )
        )
        bar.update()
    images = crop_to_content(images)
    grid, caps, titles, i = [], [], [], 0
    for r in sweep:
        grid.append(images[i : i + len(r.settings)])
        caps.append([caption(p, None if r.name == "random" else r.name, shown=None if space is None else space.active(p)) for p in r.settings])
        titles.append("random unseen settings" if r.name == "random" else f"sweep of {r.name}")
        i += len(r.settings)
    return contact_sheet(grid, caps, titles, title=title)


def render_turntable(model: Any, base: dict[str, Any], names: Sequence[str], svc: Any, up: str, frames: int, size: int, seed: int = 0, quiet: bool = False) -> list[np.ndarray]:
    """Frames of the sweep's turntable: the camera circles once while ``names`` follow
    :func:`turntable_path`; every frame is a real-time transfer by ``svc`` (a ``FamilyService``)."""
    shapes = [model.generate(p) for p in turntable_path(model.space, base, names, frames)]
    center, radius = bounding_sphere(np.concatenate([s.vertices for s in shapes]))
    bar = Progress("turntable", frames, quiet=quiet)
    out = []
    for f, shape in enumerate(shapes):
        result = transfer(shape, svc.assets, svc.mapper, seed=seed, painter=svc.painter)
        cam = orbit_camera(center, radius, up, -35.0 + 360.0 * f / frames, 20.0, size, fov_deg=32.0)
        maps = None if svc.assets.pbr is None else list(svc.assets.pbr) + [None] * len(result.new_textures)
        out.append(
            render_textured(
                shape.vertices, shape.faces, result.corner_uv, result.face_group, list(svc.assets.textures) + list(result.new_textures), cam, tracer=Tracer(shape.vertices, shape.faces), maps=maps
            )
        )
        bar.update()
    return out


# ------------------------------------------------------------------------------------------ driver
@dataclass
class DemoResult:
    """Where a demo wrote its outputs, and its summary (also in ``demo.json``)."""

    out: str
    report: str
    contact_sheet: str
    turntable: str
    variants: list[str]
    summary: dict[str, Any] = field(default_factory=dict)


def family_title(config: Any) -> str:
    """A family's source in a few words: the built-in model's name, ``file.blend:Object`` or
    ``generator``."""
    src = config.source
    if src.model:
        return src.model
    if src.blender:
        return f"{Path(str(src.blender.get('file', 'model.blend'))).name}:{src.blender.get('object', '?')}"
    return "generator"


def finish_demo(
    out: str | os.PathLike,
    family: str,
    stage_seconds: dict[str, float],
    ray: bool = False,
    rows: int = 3,
    per_row: int = 5,
    frames: int = 48,
    size: int = 320,
    gif_size: int = 320,
    seed: int = 0,
    log: Callable[[str], None] = print,
    quiet: bool = False,
    started: float | None = None,
    look: str | None = None,
) -> DemoResult:
    """Sweep, transfer, render and report a built family (of a procedural model) into ``out``, in
    its ``look`` (default: the build's).

    Writes ``variants/<row>_<k>.glb`` (+ ``variants.json``), ``contact_sheet.png``, ``turntable.gif``,
    ``report.html`` and ``demo.json``. ``stage_seconds``: the build's wall time per stage;
    ``started``: ``time.perf_counter()`` when the whole job began (for its total wall time).
    """
    t_start = time.perf_counter()
    out = Path(out)
    store = FamilyStore(family)
    config = stored_config(store)
    if config.shapes().model is None:
        raise ValueError("a contact sheet sweeps parameters: the family must come from a model, a generator or a .blend file, not a folder")
    (out / "variants").mkdir(parents=True, exist_ok=True)
    model = config.procedural_model()
    svc = FamilyService(store, look=look)
    up = config.up_axis()
    template_params = svc.state.stage("template").get("params")
    base = model.space.validate(template_params if isinstance(template_params, dict) else model.space.defaults())
    effects = parameter_effects(model.space, base, model.generate)
    sweep = sweep_settings(model.space, base, effects, rows=rows, per_row=per_row, seed=seed)

    # Transfer every variant (the real-time path: the networks, no cage solve) and keep its arrays.
    bar = Progress("transfer", sum(len(r.settings) for r in sweep), quiet=quiet)
    variants: list[dict[str, Any]] = []
    rendered: list[tuple[Any, Any]] = []
    for r in sweep:
        for k, params in enumerate(r.settings):
            shape = model.generate(params)
            answer = shape_to_glb(shape, svc.assets, svc.mapper, seed=seed, painter=svc.painter, up=up)
            result = answer.result
            rel = f"variants/{r.name}_{k}.glb"
            atomic_write(out / rel, answer.data)
            variants.append({"row": r.name, "index": k, "params": params, "glb": rel, "seconds": round(result.seconds, 4), "faces": int(shape.n_faces), "notes": result.notes})
            rendered.append((shape, result))
            bar.update()
    atomic_write(out / "variants.json", json.dumps(variants, indent=1))

    sheet = render_sheet(sweep, rendered, svc.assets.textures, up, size, title=f'{family_title(config)}: "{svc.paint.prompt}"', quiet=quiet, maps=svc.assets.pbr, space=model.space)
    save_png(out / "contact_sheet.png", sheet)
    swept = [r.name for r in sweep if r.name != "random"][:2]
    spin = render_turntable(model, base, swept, svc, up, frames, gif_size, seed=seed, quiet=quiet)
    save_gif(out / "turntable.gif", spin, fps=12)

    # The report.
    paint = store.read_json(StoreLayout.PAINT)
    trained = svc.state.stage("train").get("groups", {})

    fam_rel = os.path.relpath(store.base, out)
    groups = []
    for g in paint["groups"]:
        gi = g["group"]
        info = trained.get(str(gi)) if isinstance(trained, dict) else None
        net = "trained" if gi in svc.models else "none (same connectivity everywhere: template UVs)"
        if isinstance(info, dict) and info.get("iterations"):
            net = f"trained, {info['iterations']} iterations"
        groups.append({"group": gi, "label": g.get("label"), "prompt": g.get("prompt"), "texture": f"{fam_rel}/{StoreLayout.texture(gi, g.get('label') or '')}", "network": net})
    metrics = store.read_json(StoreLayout.METRICS) if store.exists(StoreLayout.METRICS) else None
    secs = [v["seconds"] for v in variants]
    stage_all = {**{k: float(v) for k, v in stage_seconds.items()}, "sweep + renders + report": time.perf_counter() - t_start}
    notes = sorted({n for v in variants for n in v["notes"]})
    summary = {
        "model": family_title(config),
        "prompt": svc.paint.prompt,
        "look": svc.look.name,
        "family": fam_rel,
        "serve_root": os.path.dirname(fam_rel) or ".",
        "seed": config.seed,
        "n_train": config.source.n_train,
        "n_test": config.source.n_test,
        "ray": ray,
        "groups": groups,
        "metrics": None
        if metrics is None
        else {
            "shapes": metrics["shapes"],
            "tracker": metrics.get("tracker"),
            "methods": {k: {kk: vv for kk, vv in m.items() if kk not in ("per_shape", "per_group")} for k, m in metrics["methods"].items()},
        },
        "stage_seconds": {k: round(v, 2) for k, v in stage_all.items()},
        "total_seconds": round(time.perf_counter() - started if started is not None else sum(stage_all.values()), 2),
        "variants": variants,
        "transfer_median_seconds": float(np.median(secs)),
        "contact_sheet": "contact_sheet.png",
        "turntable": "turntable.gif",
        "sweep": [{"row": r.name, "n": len(r.settings)} for r in sweep],
        "effects": {k: round(v, 4) for k, v in effects.items()},
        "notes": notes,
    }
    atomic_write(out / "demo.json", json.dumps(summary, indent=1, default=str))
    atomic_write(out / "report.html", report_html(summary))
    log(f"demo: {len(variants)} variants, median transfer {1000 * summary['transfer_median_seconds']:.0f} ms, outputs in {out}")
    return DemoResult(str(out), str(out / "report.html"), str(out / "contact_sheet.png"), str(out / "turntable.gif"), [str(out / v["glb"]) for v in variants], summary)


def build_in_process(root: str, config_dict: dict[str, Any], log: Callable[[str], None] = print) -> dict[str, float]:
    """Build a family in this process; returns wall seconds per stage."""
    return build(FamilyStore(root), BuildConfig.from_dict(config_dict), log=log)["wall_seconds"]


Builder = Callable[[str, dict[str, Any]], dict[str, float]]


def run_demo(
    out: str | os.PathLike,
    model: str = DEMO_MODEL,
    prompt: str = DEMO_PROMPT,
    group_prompts: dict[str, str] | None = None,
    seed: int = 0,
    n_train: int = 10,
    n_test: int = 3,
    rows: int = 3,
    per_row: int = 5,
    frames: int = 48,
    fresh: bool = False,
    builder: Builder | None = None,
    ray: bool = False,
    log: Callable[[str], None] = print,
    quiet: bool = False,
    overrides: dict[str, Any] | None = None,
) -> DemoResult:
    """The main job: build a family of ``model`` painted with ``prompt`` into ``out/families/<model>``
    (``builder(root, config) -> stage seconds``; default: in this process), then :func:`finish_demo`.

    ``fresh`` deletes an earlier demo family in ``out`` first; otherwise a finished one is reused
    (every stage skips) and one built with other settings is an error. ``overrides``: build config
    fields replacing :func:`demo_config`'s (e.g. fewer iterations in tests).
    """
    import shutil

    if not prompt or not prompt.strip():
        raise ValueError("the prompt must not be empty")

    config = merge(demo_config(model, prompt, seed=seed, n_train=n_train, n_test=n_test, group_prompts=group_prompts), sections(overrides or {}, where="overrides"))
    checked = BuildConfig.from_dict(config).to_dict()  # validates the model name and settings before any work
    out = Path(out)
    root = out / "families" / model
    if fresh and root.exists():
        shutil.rmtree(root)
    if root.exists() and (root / StoreLayout.STATE).exists():
        old = FamilyState.load(FamilyStore(root)).config
        if old is not None and resolved_settings(old) != checked:
            raise ValueError(f"{root} holds a family built with other settings; pass --fresh to rebuild it, or choose another --out")
    root.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    log(f"demo: building the {model!r} family painted with {prompt!r} into {root}")
    walls = (builder or (lambda r, c: build_in_process(r, c, log=log)))(str(root), config)
    log(f"demo: family built in {time.perf_counter() - t0:.1f}s")
    return finish_demo(out, str(root), walls, ray=ray, rows=rows, per_row=per_row, frames=frames, seed=seed, log=log, quiet=quiet, started=t0)
