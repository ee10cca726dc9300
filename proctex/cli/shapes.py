"""The commands on single shapes and models: ``models``, ``sample``, ``segment``, ``match``,
``correspond``, ``paint``, ``render`` and ``template``."""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

from proctex.geometry.matching import match_groups
from proctex.geometry.meshio import load_mesh, save_mesh, save_params
from proctex.geometry.parts import Grouping, analyse
from proctex.models import get_model, list_models
from proctex.params import select_template
from proctex.progress import track
from proctex.sources.files import FolderSource, resolve_model, resolve_shape

from .common import (
    _check_preview_path,
    _group_prompts,
    _print_json,
    check_output_file,
    finite,
)


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
    finite("--tol", args.tol, 1e-6, 1.0)
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


def cmd_paint(args: argparse.Namespace) -> int:
    from proctex.store.template import write_textured
    from proctex.texture.paint import resolve_group_prompts
    from proctex.texture.paint_loop import paint_template
    from proctex.texture.render import default_up

    if args.size < 8 or args.size > 8192:
        raise ValueError(f"--size must be in [8, 8192], got {args.size}")
    if args.views < 3 or args.view_size < 16:
        raise ValueError("--views must be >= 3 and --view-size >= 16")
    if args.painter == "diffusion" and not args.model_dir:
        raise ValueError("--painter diffusion needs --model-dir (a local diffusers model folder)")
    group_prompts = _group_prompts(args.group_prompts)
    check_output_file(args.preview, args.force, "--preview")
    _check_preview_path(args.preview)
    shape = resolve_shape(args.mesh)
    up = default_up(shape.source) if args.up == "auto" else args.up
    grouping = analyse(shape, seed=args.seed)
    resolve_group_prompts(grouping, args.prompt, group_prompts, shape, up)  # validates the keys before any work

    def progress(k: int, n: int, st: dict[str, Any]) -> None:
        if not args.quiet:
            print(
                f"view {k + 1}/{n} {st['camera']}: generate {st['generate']} refine {st['refine']} keep {st['keep']} px, "
                f"{st['texels_updated']} texels ({st['painter_s'] + st['backproject_s'] + st['render_s']:.2f}s)",
                flush=True,
            )

    t0 = time.perf_counter()
    tex = paint_template(
        shape,
        grouping,
        args.prompt,
        group_prompts,
        painter=args.painter,
        size=args.size,
        seed=args.seed,
        up=up,
        views=args.views,
        view_size=args.view_size,
        model_dir=args.model_dir,
        device=args.device,
        steps=args.steps,
        on_view=progress,
        occlusion=args.occlusion,
    )
    seconds = time.perf_counter() - t0
    summary = write_textured(tex, args.out, up=up, obj=args.obj)
    summary["paint_seconds"] = round(seconds, 3)
    if args.preview:
        from proctex.texture.render import render_three_quarter, save_png

        image = render_three_quarter(
            tex.shape.vertices, tex.shape.faces, tex.uv.corner_uv, tex.uv.face_group, [g.uint8() for g in tex.groups], up=up, size=512, maps=tex.pbr if any(m is not None for m in tex.pbr) else None
        )
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


def cmd_render(args: argparse.Namespace) -> int:
    from proctex.texture.gltf_read import read_textured_glb
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
    check_output_file(out, args.force)
    mesh = read_textured_glb(args.file)
    up = default_up(args.file) if args.up == "auto" else args.up
    arrays = (mesh.vertices, mesh.faces, mesh.corner_uv, mesh.face_group, mesh.textures)
    tracer = Tracer(mesh.vertices, mesh.faces)
    maps = mesh.pbr if any(m is not None for m in mesh.pbr) else None  # PBR materials are lit physically
    lit = {"maps": maps, "normals": mesh.corner_normals}  # with the file's own normals
    if args.views == "front":
        image, what = render_three_quarter(*arrays, up=up, size=args.size, tracer=tracer, **lit), "3/4 view"
    elif args.views == "six":
        images, names = render_six_views(*arrays, up=up, size=args.size, tracer=tracer, **lit)
        image, what = render_grid(images, 3, labels=names), "six views"
    else:
        frames = turntable_frames(*arrays, up=up, n=args.frames, size=args.size, tracer=tracer, **lit)
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
