"""The ``proctex`` command line.

Every command validates its input and answers bad input with ``error: ...`` on stderr and exit
status 2, without writing partial output.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

from proctex.family.sources import FolderSource, resolve_model, resolve_shape
from proctex.geometry.meshio import load_mesh, save_mesh, save_params
from proctex.geometry.parts import Grouping, analyse, match_groups
from .models import get_model, list_models
from .params import select_template
from .progress import track


def _print_json(data: Any) -> None:
    print(json.dumps(data, indent=2))


# -------------------------------------------------------------------------------------- commands
def cmd_models(args: argparse.Namespace) -> int:
    models = [get_model(n).describe() for n in list_models()]
    if args.json:
        _print_json({"models": models})
        return 0
    for m in models:
        print(f"{m['name']}: {m['description']}")
        for p in m["params"]:
            rng = p["options"] if p["kind"] == "choice" else f"[{p['low']}, {p['high']}]"
            unit = f" {p['unit']}" if p.get("unit") else ""
            print(f"    {p['name']:<18} {p['kind']:<10} {rng}{unit}  default {p['default']}")
    return 0


def cmd_sample(args: argparse.Namespace) -> int:
    model = resolve_model(args.model)
    if args.n < 1:
        raise ValueError(f"--n must be >= 1, got {args.n}")
    samples = model.space.sample(args.n, seed=args.seed, method=args.method)
    shapes = [model.generate(p) for p in track(samples, "generate", len(samples), args.quiet)]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for i, (p, shape) in enumerate(zip(samples, shapes)):
        save_mesh(shape, out / f"{i}.{args.format}")
        save_params(p, out / f"{i}.json")
    if not args.quiet:
        print(f"wrote {len(samples)} samples of {model.name} to {out}", file=sys.stderr)
    return 0


def segment_summary(grouping: Grouping) -> dict[str, Any]:
    d = grouping.to_dict()
    d["n_parts"] = len(d["parts"])
    d["n_groups"] = len(d["groups"])
    return d


def cmd_segment(args: argparse.Namespace) -> int:
    if os.path.isfile(args.mesh):
        shape, report = load_mesh(args.mesh, connectivity=args.connectivity)
        load_info = report.to_dict()
    else:
        shape, load_info = resolve_shape(args.mesh), None
    grouping = analyse(shape, tol=args.tol, seed=args.seed)
    summary = segment_summary(grouping)
    if load_info is not None:
        summary["load"] = load_info
    if args.json:
        _print_json(summary)
        return 0
    print(f"{args.mesh}: {shape.n_vertices} vertices, {shape.n_faces} faces, {summary['n_parts']} parts, {summary['n_groups']} groups")
    for note in (load_info or {}).get("notes", []):
        print(f"  note: {note}")
    for p in summary["parts"]:
        flags = " degenerate" if p["degenerate"] else (" tiny" if p["tiny"] else "")
        print(f"  part {p['index']:>3}: {p['faces']:>6} faces  area {p['area']:.4g}  group {p['group']}{flags}")
    for g in summary["groups"]:
        mirrored = f"  mirrored {g['mirrored']}" if g["mirrored"] else ""
        print(f"  group {g['index']:>3}: parts {g['parts']}{mirrored}{'  (degenerate)' if g['degenerate'] else ''}")
    return 0


def cmd_match(args: argparse.Namespace) -> int:
    shape, template = resolve_shape(args.shape), resolve_shape(args.template)
    gs, gt = analyse(shape, seed=args.seed), analyse(template, seed=args.seed)
    match = match_groups(shape, gs, template, gt, seed=args.seed)
    result = match.to_dict()
    if args.json:
        _print_json(result)
        return 0
    for m in result["matched"]:
        print(f"shape group {m['shape_group']} -> template group {m['template_group']}  cost {m['cost']:.3f} ({m['method']})")
    print(f"added: {result['added']}  missing: {result['missing']}")
    return 0


def cmd_correspond(args: argparse.Namespace) -> int:
    from proctex.correspond.cage import CageConfig
    from proctex.correspond.dense import correspond_shapes

    if args.points < 1:
        raise ValueError(f"--points must be >= 1, got {args.points}")
    cage = CageConfig(level=args.level, iterations=args.iterations, device=args.device).validate()
    shape, template = resolve_shape(args.shape), resolve_shape(args.template)
    gs, gt = analyse(shape, seed=args.seed), analyse(template, seed=args.seed)

    def report(g: Any) -> None:
        if args.json or args.quiet:
            return
        d = g.to_dict()
        line = f"group {d['group']:2d} <- shape group {d['shape_group']:2d}  {d['seconds']:6.2f}s  residual {d['residual']:.5f}  {'converged' if d['converged'] else 'not converged'} ({d['iterations']} it)"
        if d["gt_error"]:
            e = d["gt_error"]
            line += f"  gt mean {e['mean']:.4f} p95 {e['p95']:.4f} max {e['max']:.4f} flipped {100 * e['flipped']:.1f}%"
        print(line, flush=True)

    result = correspond_shapes(shape, template, method=args.method, n_points=args.points, seed=args.seed, cage=cage, grouping=gs, template_grouping=gt, on_group=report)
    data = result.to_dict()
    if args.json:
        _print_json(data)
        return 0
    for s in data["skipped"]:
        print(f"group {s['group']:2d} skipped: {s['reason']}")
    m = data["match"]
    if m["added"] or m["missing"]:
        print(f"unmatched shape groups: {m['added']}  template groups absent from the shape: {m['missing']}")
    print(f"{args.method}: {len(data['groups'])} group pairs in {data['seconds']:.2f}s")
    return 0


def _group_prompts(arg: str | None) -> dict[str, str] | None:
    """``--group-prompts``: inline JSON or the path of a JSON file, ``{"group label or index": prompt}``."""
    if not arg:
        return None
    text = Path(arg).read_text() if os.path.isfile(arg) else arg
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"--group-prompts is not valid JSON ({exc}); expected e.g. '{{\"seat\": \"red velvet\"}}'") from exc
    if not isinstance(data, dict) or not all(isinstance(v, str) for v in data.values()):
        raise ValueError('--group-prompts must be a JSON object of strings, e.g. {"seat": "red velvet", "2": "oak"}')
    return {str(k): v for k, v in data.items()}


def cmd_paint(args: argparse.Namespace) -> int:
    from proctex.family.template import write_textured
    from proctex.texture.paint import paint_template, resolve_group_prompts
    from proctex.texture.render import default_up

    if args.size < 8 or args.size > 8192:
        raise ValueError(f"--size must be in [8, 8192], got {args.size}")
    if args.views < 3 or args.view_size < 16:
        raise ValueError("--views must be >= 3 and --view-size >= 16")
    if args.painter == "diffusion" and not args.model_dir:
        raise ValueError("--painter diffusion needs --model-dir (a local diffusers model folder)")
    group_prompts = _group_prompts(args.group_prompts)
    _check_preview_path(args.preview)
    shape = resolve_shape(args.mesh)
    up = default_up(shape.source) if args.up == "auto" else args.up
    grouping = analyse(shape, seed=args.seed)
    resolve_group_prompts(grouping, args.prompt, group_prompts)  # validates the keys before any work

    def progress(k: int, n: int, st: dict[str, Any]) -> None:
        if not args.quiet:
            print(f"view {k + 1}/{n} {st['camera']}: generate {st['generate']} refine {st['refine']} keep {st['keep']} px, "
                  f"{st['texels_updated']} texels ({st['painter_s'] + st['backproject_s'] + st['render_s']:.2f}s)", flush=True)

    t0 = time.perf_counter()
    tex = paint_template(shape, grouping, args.prompt, group_prompts, painter=args.painter, size=args.size, seed=args.seed, up=up,
                         views=args.views, view_size=args.view_size, model_dir=args.model_dir, device=args.device, steps=args.steps,
                         on_view=progress)
    seconds = time.perf_counter() - t0
    summary = write_textured(tex, args.out, up=up, obj=args.obj)
    summary["paint_seconds"] = round(seconds, 3)
    if args.preview:
        from proctex.texture.render import render_three_quarter, save_png

        image = render_three_quarter(tex.shape.vertices, tex.shape.faces, tex.uv.corner_uv, tex.uv.face_group,
                                     [g.uint8() for g in tex.groups], up=up, size=512)
        Path(args.preview).parent.mkdir(parents=True, exist_ok=True)
        save_png(args.preview, image)
        summary["preview"] = args.preview
    if args.json:
        _print_json(summary)
        return 0
    if not args.quiet:
        for note in tex.notes:
            print(f"note: {note}")
        for g in summary["groups"]:
            print(f"group {g['group']} {g['label'] or '':<12} {g['prompt']!r}  {g['covered_texels']} texels  seen {100 * g['seen']:.1f}%")
        print(f"coverage (unpainted visible pixels): {100 * summary['coverage']['share']:.3f}%")
    print(f"painted {len(tex.groups)} groups ({args.painter}, {args.size}px) in {seconds:.2f}s -> {args.out}")
    if args.preview:
        print(f"wrote {args.preview} (3/4 view, 512x512)")
    return 0


def _check_preview_path(preview: str | None) -> None:
    """``--preview`` must name a .png file (checked before any work)."""
    if preview is not None and Path(preview).suffix.lower() != ".png":
        raise ValueError(f"--preview must name a .png file, got {preview!r}")


def _build_config(args: argparse.Namespace):
    from proctex.family.config import BuildConfig

    data: dict[str, Any] = {}
    if args.config and args.config_file:
        raise ValueError("give the config file once (positional CONFIG or --config)")
    config_file = args.config or args.config_file
    if config_file:
        data = {k: v for k, v in vars(BuildConfig.from_file(config_file)).items()}
    flags = {
        "model": args.model, "folder": os.path.abspath(args.folder) if args.folder else None, "prompt": args.prompt,
        "group_prompts": _group_prompts(args.group_prompts), "seed": args.seed, "n_train": args.n_train, "n_test": args.n_test,
        "texture_size": args.texture_size, "corr_points": args.points, "cage_iterations": args.iterations, "up": args.up,
        "painter": args.painter, "model_dir": os.path.abspath(args.model_dir) if args.model_dir else None,
        "tessellation": args.tessellation, "truth": args.truth,
    }
    if args.model or args.folder:  # a source flag replaces the config's source
        data.update(model=None, folder=None, generator=None)
    data.update({k: v for k, v in flags.items() if v is not None})
    if args.train_iterations is not None:
        data["train"] = {**data.get("train", {}), "iterations": args.train_iterations}
    return BuildConfig.from_dict(data)


def cmd_build(args: argparse.Namespace) -> int:
    from proctex.family.pipeline import build
    from proctex.family.stages import STAGES
    from proctex.family.store import FamilyStore

    config = _build_config(args)
    if args.ray is not None:
        raise ValueError("--ray runs through the Ray layer: use the installed `proctex` command (workflows.cli)")
    stages = tuple(args.stages.split(",")) if args.stages else STAGES
    state = build(FamilyStore(args.out), config, stages=stages, log=(lambda *_: None) if args.quiet else (lambda m: print(m, flush=True)))
    done = [k for k, v in state.get("stages", {}).items() if v.get("state") == "done"]
    print(f"family {args.out}: stages done: {', '.join(done)}")
    return 0


def cmd_transfer(args: argparse.Namespace) -> int:
    from proctex.family.mappers import make_mapper
    from proctex.family.stages import load_assets, load_models, stored_config
    from proctex.family.store import FamilyStore
    from proctex.family.transfer import bake, glb, info, transfer

    store = FamilyStore(args.family)
    config = stored_config(store)
    if bool(args.params) == bool(args.mesh):
        raise ValueError("give exactly one of --params JSON or --mesh FILE")
    if args.params:
        if config.folder:
            raise ValueError("this family comes from a folder of meshes: transfer a --mesh")
        try:
            params = json.loads(args.params)
        except json.JSONDecodeError as exc:
            raise ValueError(f"--params is not valid JSON ({exc})") from exc
        shape = config.procedural_model().generate(params)
    else:
        shape, _ = load_mesh(args.mesh)
    if not args.out.endswith(".glb"):
        raise ValueError("--out must name a .glb file")
    _check_preview_path(args.preview)
    t0 = time.perf_counter()
    assets = load_assets(store)
    models = load_models(store) if args.mapper in ("auto", "net") else None
    if args.mapper == "net" and not models:
        raise ValueError(f"{args.family} has no trained models (run the train stage)")
    mapper = make_mapper(args.mapper, assets, models, corr_points=config.corr_points, cage=config.cage_config())
    t1 = time.perf_counter()
    from proctex.texture.painters import SurfacePainter

    painter = SurfacePainter(config.prompt, seed=config.seed)  # for parts of groups the template lacks
    result = transfer(shape, assets, mapper, seed=args.seed, painter=painter)
    if args.bake:
        from proctex.texture.export import glb_bytes

        baked = bake(shape, result, assets, size=args.bake)
        names = assets.names + [f"new_{k}" for k in range(len(result.new_textures))]
        data = glb_bytes(shape.vertices, shape.faces, baked.corner_uv, baked.face_group, baked.textures, names=names, up=config.up_axis())
        textured = (baked.corner_uv, baked.face_group, list(baked.textures))
    else:
        data = glb(shape, result, assets, up=config.up_axis())
        textured = (result.corner_uv, result.face_group, list(assets.textures) + list(result.new_textures))
    from .fileio import atomic_write

    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    atomic_write(args.out, data)
    summary = {**info(result), "load_seconds": round(t1 - t0, 3), "mapper": type(mapper).__name__, "out": args.out, "bytes": len(data)}
    if args.preview:
        from proctex.texture.render import render_three_quarter, save_png

        image = render_three_quarter(shape.vertices, shape.faces, *textured, up=config.up_axis(), size=512)
        Path(args.preview).parent.mkdir(parents=True, exist_ok=True)
        save_png(args.preview, image)
        summary["preview"] = args.preview
    if args.json:
        _print_json(summary)
    else:
        for note in result.notes:
            print(f"note: {note}")
        print(f"transferred {shape.n_faces} faces with {summary['mapper']} in {result.seconds * 1000:.0f} ms "
              f"(family loaded in {t1 - t0:.1f}s) -> {args.out}")
        if args.preview:
            print(f"wrote {args.preview} (3/4 view, 512x512)")
    return 0


def cmd_render(args: argparse.Namespace) -> int:
    from proctex.texture.export import read_textured_glb
    from proctex.texture.render import (
        Tracer,
        default_up,
        grid_columns,
        render_grid,
        render_six_views,
        render_three_quarter,
        save_gif,
        save_png,
        turntable_frames,
    )

    if not os.path.isfile(args.file):
        raise ValueError(f"{args.file}: no such file")
    if not 16 <= args.size <= 4096:
        raise ValueError(f"--size must be in [16, 4096], got {args.size}")
    if not 1 <= args.frames <= 360:
        raise ValueError(f"--frames must be in [1, 360], got {args.frames}")
    if not 0 < args.fps <= 100:
        raise ValueError(f"--fps must be in (0, 100], got {args.fps}")
    out = args.out or str(Path(args.file).with_suffix(".png"))
    suffix = Path(out).suffix.lower()
    if suffix not in (".png", ".gif"):
        raise ValueError(f"--out must name a .png (or, with --views turntable, a .gif) file, got {out!r}")
    if suffix == ".gif" and args.views != "turntable":
        raise ValueError("an animated .gif needs --views turntable")
    if os.path.abspath(out) == os.path.abspath(args.file):
        raise ValueError(f"--out {out!r} would overwrite the input")
    mesh = read_textured_glb(args.file)
    up = default_up(args.file) if args.up == "auto" else args.up
    arrays = (mesh.vertices, mesh.faces, mesh.corner_uv, mesh.face_group, mesh.textures)
    tracer = Tracer(mesh.vertices, mesh.faces)
    if args.views == "front":
        image, what = render_three_quarter(*arrays, up=up, size=args.size, tracer=tracer), "3/4 view"
    elif args.views == "six":
        images, names = render_six_views(*arrays, up=up, size=args.size, tracer=tracer)
        image, what = render_grid(images, 3, labels=names), "six views"
    else:
        frames = turntable_frames(*arrays, up=up, n=args.frames, size=args.size, tracer=tracer)
        image, what = None, f"turntable, {args.frames} frames"
        if suffix != ".gif":
            image = render_grid(frames, grid_columns(len(frames)))
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    if image is None:
        save_gif(out, frames, fps=args.fps)
        what += f" at {args.fps:g} fps, {args.size}x{args.size}"
    else:
        save_png(out, image)
        what += f", {image.shape[1]}x{image.shape[0]}"
    for note in mesh.notes:
        print(f"note: {note}")
    print(f"{args.file}: {len(mesh.faces)} faces, {len(mesh.textures)} materials, up {up}")
    print(f"wrote {out} ({what})")
    return 0


def _pair(text: str | None, what: str, n: int = 2) -> tuple[float, ...] | None:
    if text is None:
        return None
    try:
        vals = tuple(float(x) for x in text.split(","))
    except ValueError as exc:
        raise ValueError(f"{what} must be numbers separated by commas, got {text!r}") from exc
    if len(vals) == 1 and n == 2:
        vals = vals * 2
    if len(vals) != n:
        raise ValueError(f"{what} needs {n} numbers, got {text!r}")
    return vals


def cmd_edit(args: argparse.Namespace) -> int:
    from proctex.family.edits import edit_group
    from proctex.family.store import FamilyStore

    store = FamilyStore(args.family)
    if args.logo is not None and not os.path.isfile(args.logo):
        raise ValueError(f"--logo {args.logo}: no such file")
    record = edit_group(
        store, args.group, hue=args.hue, saturation=args.saturation, value=args.value, logo=args.logo,
        at=_pair(args.at, "--at") or (0.5, 0.5), size=_pair(args.size, "--size") or (0.25, 0.25),
        rotation=args.rotation, opacity=args.opacity, prompt=args.prompt,
    )
    print(f"edited group {record['group']}: {', '.join(k for k in record if k != 'group')}; transfers now use it")
    return 0


def _eval_options(args: argparse.Namespace) -> dict[str, Any]:
    """Validated keyword arguments of :func:`proctex.evaluate.evaluate` from the eval flags."""
    from proctex.family.evaluate import METHODS

    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        raise ValueError(f"--methods must name some of {', '.join(METHODS)}, got {args.methods!r}")
    if args.limit is not None and args.limit < 1:
        raise ValueError(f"--limit must be >= 1, got {args.limit}")
    if args.workers < 0:
        raise ValueError(f"--workers must be >= 0 (0: one per CPU, at most 4), got {args.workers}")
    if args.lpips and not os.path.isfile(args.lpips):
        raise ValueError(f"--lpips {args.lpips!r}: no such weights file")
    if args.tracked < 10 or args.tracked > 1_000_000:
        raise ValueError(f"--tracked must be in [10, 1000000], got {args.tracked}")
    return {"methods": methods, "split": args.shapes, "limit": args.limit, "lpips": args.lpips, "truth": args.truth, "tracked": args.tracked,
            "workers": args.workers or max(1, min(4, os.cpu_count() or 1)), "quiet": args.quiet or args.json}


def run_eval(store: Any, args: argparse.Namespace, options: dict[str, Any]) -> int:
    """Evaluate, write ``metrics.json`` into the store, print the table (or the JSON)."""
    from proctex.family.evaluate import evaluate, markdown_table
    from proctex.family.store import StoreLayout

    if not store.exists(StoreLayout.MODELS) and {"corrnet", "corrnet_all"} & set(options["methods"]):
        raise ValueError(f"{store.uri}: no trained models (run the train stage, or evaluate without corrnet)")
    log = (lambda *_: None) if (args.quiet or args.json) else (lambda m: print(m, flush=True))
    metrics = evaluate(store, log=log, **options)
    store.write_json(StoreLayout.METRICS, metrics)
    if args.json:
        _print_json(metrics)
    else:
        print(markdown_table(metrics))
    return 0


def cmd_eval(args: argparse.Namespace) -> int:
    from proctex.family.stages import stored_config
    from proctex.family.store import FamilyStore

    store = FamilyStore(args.family)
    stored_config(store)  # a clear error when the folder is not a family
    return run_eval(store, args, _eval_options(args))


def cmd_eval_folder(args: argparse.Namespace) -> int:
    """Build a family from a folder of samples (train/ and inference/), then evaluate it."""
    from proctex.family.config import BuildConfig
    from proctex.family.pipeline import build
    from proctex.family.store import FamilyStore

    if not os.path.isdir(args.folder):
        raise ValueError(f"{args.folder}: no such folder")
    options = _eval_options(args)
    data: dict[str, Any] = BuildConfig.read_settings(args.config) if args.config else {}
    data.update(model=None, generator=None, folder=os.path.abspath(args.folder), prompt=args.prompt)
    if args.group_prompts:
        data["group_prompts"] = _group_prompts(args.group_prompts)
    if args.seed is not None:
        data["seed"] = args.seed
    config = BuildConfig.from_dict(data)
    out = args.out or os.path.join("out", "families", Path(os.path.abspath(args.folder)).name)
    log = (lambda *_: None) if (args.quiet or args.json) else (lambda m: print(m, flush=True))
    builder = getattr(args, "builder", None)  # the Ray layer passes one (workflows.cli)
    stages = ("sample", "template", "paint", "pairs", "train")
    if builder is not None:
        builder(out, config, stages, log)
    else:
        build(FamilyStore(out), config, stages=stages, log=log)
    return run_eval(FamilyStore(out), args, options)


def _add_eval_flags(p: argparse.ArgumentParser) -> None:
    from proctex.family.evaluate import DEFAULT_METHODS
    from proctex.family.fidelity import TRUTHS

    p.add_argument("--shapes", choices=["test", "train"], default="test")
    p.add_argument("--methods", default=",".join(DEFAULT_METHODS),
                   help="comma-separated: corrnet (the run-time path), corrnet_all (the network on every part), cage, nearest, cpd, identity")
    p.add_argument("--limit", type=int, help="evaluate only the first N shapes")
    p.add_argument("--lpips", help="a local LPIPS (AlexNet) weights file: adds LPIPS to SSIM and PSNR")
    p.add_argument("--workers", type=int, default=0, help="processes evaluating shapes in parallel (0: one per CPU, at most 4)")
    p.add_argument("--truth", choices=list(TRUTHS), default="auto",
                   help="ground truth: auto (the config's; canonical coordinates for built-in models), vertex-index (the samples share one "
                        "vertex order), canonical, or none (points tracked by the cage solver, no GT error)")
    p.add_argument("--tracked", type=int, default=5000, help="tracked template points and truth samples per shape (vertex-index: every vertex)")
    p.add_argument("--json", action="store_true")
    p.add_argument("--quiet", action="store_true")


def cmd_template(args: argparse.Namespace) -> int:
    if os.path.isdir(args.source):
        src = FolderSource(args.source)
        i = src.template_index()
        result = {"source": args.source, "template": src.samples[i].id, "mesh": src.samples[i].mesh_path, "params": src.params(i)}
    else:
        model = resolve_model(args.source)
        samples = model.space.sample(args.n, seed=args.seed, method=args.method)
        i = select_template(model.space, samples)
        result = {"source": model.name, "template": i, "params": samples[i]}
    if args.json:
        _print_json(result)
    else:
        print(f"template: {result['template']}  params: {json.dumps(result['params'])}")
    return 0


def cmd_gallery(args: argparse.Namespace) -> int:
    from PIL import Image

    from proctex.geometry.preview import face_label_colors, grid_image, render_faces

    names = args.models or list_models()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name in track(names, "gallery", len(names), args.quiet):
        model = get_model(name)
        settings = [model.space.defaults()] + model.space.sample(2, seed=args.seed, method="lhs")
        row = []
        for p in settings:
            s = model.generate(p)
            row.append(render_faces(s.vertices, s.faces, face_label_colors(s), size=args.size, azimuth=-60, elevation=25))
        Image.fromarray(grid_image([row])).save(out / f"{name}.png")
    if not args.quiet:
        print(f"wrote {len(names)} previews to {out}", file=sys.stderr)
    return 0


def demo_arguments(args: argparse.Namespace) -> dict[str, Any]:
    """Validated keyword arguments of :func:`proctex.demo.run_demo` from the ``demo`` flags."""
    if args.n_train < 2 or args.n_test < 0:
        raise ValueError(f"--n-train must be >= 2 and --n-test >= 0, got {args.n_train}, {args.n_test}")
    if args.rows < 0 or args.per_row < 1 or args.frames < 1:
        raise ValueError("--rows must be >= 0, --per-row >= 1 and --frames >= 1")
    return {"model": args.model, "prompt": args.prompt, "group_prompts": _group_prompts(args.group_prompts), "seed": args.seed,
            "n_train": args.n_train, "n_test": args.n_test, "rows": args.rows, "per_row": args.per_row, "frames": args.frames,
            "fresh": args.fresh, "quiet": args.quiet}


def print_demo_outputs(result: Any) -> None:
    s = result.summary
    fam = Path(result.out) / "families" / s["model"]
    print(f"demo done in {s['total_seconds']:.0f}s ({len(result.variants)} variants, median transfer "
          f"{1000 * s['transfer_median_seconds']:.0f} ms). Look at:")
    for what, where in (("report", result.report), ("contact sheet", result.contact_sheet), ("turntable", result.turntable),
                        ("variants", f"{Path(result.out) / 'variants'}/ ({len(result.variants)} GLBs)"), ("family store", fam),
                        ("studio", f"proctex serve {fam.parent}  ->  http://127.0.0.1:8000/")):
        print(f"  {what:<14}{where}")


def cmd_demo(args: argparse.Namespace) -> int:
    """The main job in this process (the installed ``proctex demo`` builds on a local Ray instead)."""
    from .demo import run_demo

    log = (lambda *_: None) if args.quiet else (lambda m: print(m, flush=True))
    print_demo_outputs(run_demo(args.out, log=log, **demo_arguments(args)))
    return 0


# ------------------------------------------------------------------------------------------ main
def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="proctex", description="Consistent texturing of procedural shape families.")
    sub = parser.add_subparsers(dest="command", required=True)
    parser.subparsers = sub  # type: ignore[attr-defined]  # the Ray layer (workflows.cli) extends them

    p = sub.add_parser("models", help="list built-in models and their parameter specs")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_models)

    p = sub.add_parser("sample", help="sample a model into a folder of meshes + JSON parameters")
    p.add_argument("model", help="built-in model name or a generator config (.json/.toml)")
    p.add_argument("--n", type=int, required=True)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", required=True)
    p.add_argument("--method", choices=["random", "lhs"], default="random")
    p.add_argument("--format", choices=["obj", "ply", "glb", "stl"], default="obj")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=cmd_sample)

    p = sub.add_parser("segment", help="parts and part groups of a mesh (file, MODEL or MODEL:{json})")
    p.add_argument("mesh")
    p.add_argument("--json", action="store_true")
    p.add_argument("--connectivity", choices=["auto", "index", "stitch", "weld"], default="auto")
    p.add_argument("--tol", type=float, default=0.01, help="grouping tolerance relative to part size")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=cmd_segment)

    p = sub.add_parser("match", help="match the part groups of a shape to a template's")
    p.add_argument("shape")
    p.add_argument("template")
    p.add_argument("--json", action="store_true")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=cmd_match)

    p = sub.add_parser("correspond", help="dense correspondence of every matched part group of a shape onto the template")
    p.add_argument("shape", help="mesh file, MODEL or MODEL:{json}")
    p.add_argument("template", help="mesh file, MODEL or MODEL:{json}")
    p.add_argument("--method", choices=["cage", "nearest", "cpd"], default="cage")
    p.add_argument("--points", type=int, default=2000, help="source surface samples per group pair")
    p.add_argument("--level", type=int, default=1, help="cage subdivision level (2**level segments per axis)")
    p.add_argument("--iterations", type=int, default=300, help="maximum cage optimisation steps")
    p.add_argument("--device", default="cpu", help="torch device for the cage solver (cpu or cuda)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", action="store_true")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=cmd_correspond)

    p = sub.add_parser("paint", help="texture a template from a prompt: per-group PNGs, textured GLB, six-view preview")
    p.add_argument("mesh", help="mesh file, MODEL or MODEL:{json}")
    p.add_argument("--prompt", required=True, help='e.g. "dark walnut" or "red velvet with white polka dots"')
    p.add_argument("--group-prompts", help='JSON (inline or a file) overriding the prompt per group label or index, e.g. {"seat": "red velvet"}')
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", required=True)
    p.add_argument("--size", type=int, default=1024, help="texture size per group")
    p.add_argument("--painter", choices=["surface", "views", "diffusion"], default="surface",
                   help="surface: solid materials at texels; views: the multi-view loop with the solid materials; diffusion: the multi-view loop with a local diffusers model")
    p.add_argument("--views", type=int, default=11, help="camera path length for view painters")
    p.add_argument("--view-size", type=int, default=512)
    p.add_argument("--model-dir", help="local diffusers model folder (diffusion painter)")
    p.add_argument("--steps", type=int, default=30, help="diffusion steps")
    p.add_argument("--device", default="cpu")
    p.add_argument("--up", choices=["auto", "x", "y", "z"], default="auto", help="up axis (auto: y for OBJ/glTF files, else z)")
    p.add_argument("--obj", action="store_true", help="also write OBJ + MTL")
    p.add_argument("--preview", metavar="PNG", help="also write a 512px 3/4 view of the painted template to this .png")
    p.add_argument("--json", action="store_true")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=cmd_paint)

    p = sub.add_parser("build", help="build a family: sample, template, paint, cage pairs, train (into a store folder)")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--model", help="built-in model name")
    src.add_argument("--folder", help="folder of samples (mesh + JSON params, train/ and inference/)")
    p.add_argument("config_file", nargs="?", metavar="CONFIG", help="JSON or TOML build config (same as --config)")
    p.add_argument("--config", help="JSON or TOML build config (flags override it)")
    p.add_argument("--ray", nargs="?", const="local", metavar="ADDRESS",
                   help="run on Ray: a private local instance, or the cluster at ADDRESS ('auto', 'host:port')")
    p.add_argument("--train-workers", type=int, help="Ray Train workers per group network (--ray; default min(2, CPUs))")
    p.add_argument("--max-in-flight", type=int, help="Ray tasks submitted at a time (--ray; default 2 x CPUs)")
    p.add_argument("--prompt")
    p.add_argument("--group-prompts")
    p.add_argument("--out", required=True, help="family folder or URI")
    p.add_argument("--seed", type=int)
    p.add_argument("--n-train", type=int)
    p.add_argument("--n-test", type=int)
    p.add_argument("--texture-size", type=int)
    p.add_argument("--points", type=int, help="cage correspondence points per pair")
    p.add_argument("--iterations", type=int, help="cage solver iterations per pair")
    p.add_argument("--train-iterations", type=int, help="ProcCorrNet training iterations")
    p.add_argument("--up", choices=["auto", "x", "y", "z"])
    p.add_argument("--painter", choices=["surface", "views", "diffusion"], help="template painter (default surface)")
    p.add_argument("--model-dir", help="local diffusers model folder (--painter diffusion)")
    p.add_argument("--tessellation", choices=["adaptive", "fixed"],
                   help="built-in models: segments follow part sizes (adaptive, the default) or fixed counts")
    p.add_argument("--truth", choices=["auto", "canonical", "vertex-index", "none"],
                   help="what the evaluation takes as ground truth (vertex-index: the samples share one vertex order)")
    p.add_argument("--stages", help="comma-separated subset of sample,template,paint,pairs,train,evaluate")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=cmd_build)

    p = sub.add_parser("transfer", help="texture a new shape of a family: textured GLB")
    p.add_argument("family")
    p.add_argument("--params", help="parameters (JSON) for the family's model")
    p.add_argument("--mesh", help="a mesh file of the family")
    p.add_argument("--out", required=True, help="output .glb")
    p.add_argument("--mapper", choices=["auto", "net", "cage", "nearest", "identity"], default="auto")
    p.add_argument("--bake", type=int, default=0, help="bake into the shape's own atlas at this size (0: read the template textures)")
    p.add_argument("--preview", metavar="PNG", help="also write a 512px 3/4 view of the textured shape to this .png")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_transfer)

    p = sub.add_parser("render", help="render a textured GLB (e.g. a transfer result) to a PNG, or a turntable GIF")
    p.add_argument("file", metavar="FILE.glb", help="textured .glb (or .gltf) file")
    p.add_argument("--out", help="output .png (or .gif with --views turntable); default: FILE with a .png suffix")
    p.add_argument("--size", type=int, default=512, help="pixels per view (square)")
    p.add_argument("--views", choices=["front", "six", "turntable"], default="front",
                   help="front: one 3/4 view; six: the six canonical views (3x2, labelled); turntable: --frames views around the up axis")
    p.add_argument("--frames", type=int, default=24, help="turntable frames")
    p.add_argument("--fps", type=float, default=12.0, help="turntable GIF frame rate")
    p.add_argument("--up", choices=["auto", "x", "y", "z"], default="auto", help="up axis (auto: y for glTF/OBJ files, else z)")
    p.set_defaults(func=cmd_render)

    p = sub.add_parser("edit", help="edit one group's template texture (re-paint, HSV shift, logo); applies to every transfer")
    p.add_argument("family")
    p.add_argument("--group", required=True, help="group index or label")
    p.add_argument("--prompt", help="re-paint the group with this prompt")
    p.add_argument("--hue", type=float, default=0.0, help="hue shift in degrees")
    p.add_argument("--saturation", type=float, default=1.0, help="saturation scale")
    p.add_argument("--value", type=float, default=1.0, help="value (brightness) scale")
    p.add_argument("--logo", help="image file to place on the texture")
    p.add_argument("--at", help="UV centre of the image, e.g. 0.5,0.5")
    p.add_argument("--size", help="UV size of the image, e.g. 0.2 or 0.3,0.1")
    p.add_argument("--rotation", type=float, default=0.0)
    p.add_argument("--opacity", type=float, default=1.0)
    p.set_defaults(func=cmd_edit)

    p = sub.add_parser("eval", help="measure a built family on its unseen shapes, methods side by side (metrics.json + a table)")
    p.add_argument("family")
    _add_eval_flags(p)
    p.set_defaults(func=cmd_eval)

    p = sub.add_parser("eval-folder", help="build a family from a folder of samples (train/, inference/), then evaluate it")
    p.add_argument("folder")
    p.add_argument("--prompt", required=True)
    p.add_argument("--group-prompts")
    p.add_argument("--seed", type=int)
    p.add_argument("--config", help="JSON or TOML build settings (corr_points, train, ...); the folder and prompt come from the flags")
    p.add_argument("--out", help="family folder (default out/families/<folder name>; a finished build there is reused)")
    _add_eval_flags(p)
    p.set_defaults(func=cmd_eval_folder)

    p = sub.add_parser("template", help="pick the template of a folder of samples or of a model's samples")
    p.add_argument("source", help="folder of samples, model name or generator config")
    p.add_argument("--n", type=int, default=32)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--method", choices=["random", "lhs"], default="random")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_template)

    p = sub.add_parser("gallery", help="render every built-in model at three parameter settings (PNG)")
    p.add_argument("--out", default="out/gallery")
    p.add_argument("--models", nargs="*")
    p.add_argument("--size", type=int, default=256)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=cmd_gallery)

    p = sub.add_parser("demo", help="the main job: build a family, transfer a sweep of unseen settings, GLBs, contact sheet, turntable, HTML report")
    p.add_argument("--model", default="sofa", help="built-in model (default sofa)")
    p.add_argument("--prompt", default="a patchwork bohemian sofa", help="what to paint")
    p.add_argument("--group-prompts", help='JSON overriding the prompt per group label or index, e.g. {"leg": "black steel"}')
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="out/demo")
    p.add_argument("--n-train", type=int, default=10, help="training shapes of the family")
    p.add_argument("--n-test", type=int, default=3, help="unseen shapes for the metrics")
    p.add_argument("--rows", type=int, default=3, help="parameters swept on the contact sheet (plus one row of random settings)")
    p.add_argument("--per-row", type=int, default=5, help="variants per row")
    p.add_argument("--frames", type=int, default=48, help="turntable frames")
    p.add_argument("--fresh", action="store_true", help="delete an earlier demo family in --out and rebuild")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=cmd_demo)
    return parser


def run(parser: argparse.ArgumentParser, argv: list[str] | None = None) -> int:
    """Parse and run a command; bad input (``ValueError``) prints ``error: ...`` and returns 2."""
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


def main(argv: list[str] | None = None) -> int:
    return run(build_parser(), argv)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
