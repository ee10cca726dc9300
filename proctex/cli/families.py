"""The commands on families: ``build``, ``transfer``, ``edit``, ``eval``, ``gallery`` and
``demo`` (the in-process build; ``workflows.cli`` adds the Ray layer)."""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from proctex.geometry.meshio import load_mesh
from proctex.models import get_model, list_models
from proctex.progress import track

from .common import (
    _check_preview_path,
    _group_prompts,
    _pair,
    _print_json,
    check_output_file,
    json_strings,
)


def build_config_of(args: argparse.Namespace):
    """The build config of ``proctex build``: the ``--preset``, the config file over it, the flags over both."""
    from proctex.store.config import BuildConfig, merge, sections

    if args.config and args.config_file:
        raise ValueError("give the config file once (positional CONFIG or --config)")
    config_file = args.config or args.config_file
    data: dict[str, Any] = BuildConfig.read_settings(config_file) if config_file else {}
    flags = {
        "model": args.model,
        "folder": os.path.abspath(args.folder) if args.folder else None,
        "prompt": args.prompt,
        "group_prompts": _group_prompts(args.group_prompts),
        "seed": args.seed,
        "n_train": args.n_train,
        "n_test": args.n_test,
        "texture_size": args.texture_size,
        "corr_points": args.points,
        "cage_iterations": args.iterations,
        "up": args.up,
        "painter": args.painter,
        "model_dir": os.path.abspath(args.model_dir) if args.model_dir else None,
        "tessellation": args.tessellation,
        "truth": args.truth,
    }
    if args.blend:
        if not args.object:
            raise ValueError("--blend needs --object (the object carrying the Geometry Nodes modifier)")
        flags["blender"] = {"file": os.path.abspath(args.blend), "object": args.object, "modifier": args.modifier}
        flags["blender"].update({k: v for k, v in (("parts", args.parts_attribute), ("uv", args.keep_uv)) if v})
    if args.model or args.folder or args.blend:  # a source flag replaces the config's (and the preset's) source
        data = merge(data, {"source": {"model": None, "folder": None, "generator": None, "blender": None}})
    data = merge(data, sections({k: v for k, v in flags.items() if v is not None}))
    if args.params_spec:
        data = merge(data, {"source": {"params_spec": os.path.abspath(args.params_spec)}})
    if args.train_iterations is not None:
        data = merge(data, {"train": {"iterations": args.train_iterations}})
    if args.device is not None:
        from proctex.correspond.corrnet import resolve_device

        resolve_device(args.device)  # CUDA asked for and absent: said now, not halfway through the build
        data = merge(data, {"paint": {"device": args.device}, "cage": {"device": args.device}, "train": {"device": args.device}})
    return BuildConfig.from_dict(data, preset=args.preset)


def cmd_build(args: argparse.Namespace) -> int:
    from proctex.build.pipeline import build
    from proctex.build.plan import local_executor
    from proctex.store.layout import FamilyStore
    from proctex.store.state import STAGES

    config = build_config_of(args)
    check_build_look(args)
    stages = tuple(args.stages.split(",")) if args.stages else STAGES
    state = build(
        FamilyStore(args.out),
        config,
        stages=stages,
        log=(lambda *_: None) if args.quiet else (lambda m: print(m, flush=True)),
        executor=local_executor(build_workers(args.workers), min_jobs=0 if args.workers else None),
    )
    done = [k for k, v in state.get("stages", {}).items() if v.get("state") == "done"]
    print(f"family {args.out}: stages done: {', '.join(done)}{named_look(args)}")
    return 0


def build_workers(workers: int) -> int:
    """``--workers``: processes for the build's parallel stages (the cage pairs, the networks); 0:
    one per CPU, at most 4, used where a stage has enough jobs (``Plan.pool_min_jobs``)."""
    if workers < 0 or workers > 256:
        raise ValueError(f"--workers must be in 0..256 (0: one per CPU, at most 4), got {workers}")
    from proctex.build.plan import default_workers

    return workers or default_workers()


def check_build_look(args: argparse.Namespace) -> None:
    """``build --look NAME``: the name checked before any work."""
    if args.look is not None:
        from proctex.store.layout import check_look_name

        check_look_name(args.look)


def named_look(args: argparse.Namespace) -> str:
    """After a build: its look named as ``--look`` says (once painted); the line's tail saying so."""
    from proctex.store.layout import FamilyStore, StoreLayout

    store = FamilyStore(args.out)
    if args.look is None or not store.exists(StoreLayout.PAINT):
        return ""
    from proctex.looks import name_built_look

    name_built_look(store, args.look)
    return f"; its look: {args.look}"


def cmd_inputs(args: argparse.Namespace) -> int:
    """The modifier's inputs: name, type, the file's value (what the modifier holds), the node
    group's default, Blender's range, and what a build does with it: varies it, or holds it at the
    file's value (no usable range, or a spec that does not list it); with ``--params-spec`` what the
    spec gives each and the keys it did not understand."""
    from proctex.params import read_params_spec
    from proctex.sources.blender import UNBOUNDED, BlenderSession, file_value

    if not os.path.isfile(args.blend):
        raise ValueError(f"no such file: {args.blend}")
    spec = read_params_spec(args.params_spec) if args.params_spec else None
    from proctex.sources.provenance import MAX_NAMES, model_words, producer_names

    session = BlenderSession(args.blend, args.object, args.modifier)
    try:
        inputs = session.inputs
        named = producer_names(session.producers, model_words(session.object_name, session.tree))
    finally:
        session.close()
    names = list(dict.fromkeys(n.name for n in named.values() if n.name))  # what the node tree calls its parts
    rows = []
    for s in inputs:
        row = {k: s.get(k) for k in ("name", "type", "default", "min", "max", "options") if s.get(k) is not None}
        if s["type"] == "float" and isinstance(row.get("default"), (int, float)):
            row["default"] = file_value({**s, "value": s["default"]})  # single precision as typed: 0.4, not 0.4000000059604645
        row["value"] = file_value(s)
        unbounded = s["type"] in ("float", "int") and max(abs(float(s.get("min", 0))), abs(float(s.get("max", 0)))) > UNBOUNDED
        listed = spec is None or s["name"] in spec.kinds
        row["needs_bounds"] = bool(unbounded and listed and not (spec and s["name"] in spec.bounds))
        row["fixed"] = bool(not listed or row["needs_bounds"])
        if row["fixed"]:
            row["why_fixed"] = "the spec does not list it" if not listed else "no usable range in Blender: give it bounds to vary it"
        if spec is not None:
            row["spec"] = {"range": spec.bounds.get(s["name"]), **spec.conditions.get(s["name"], {})} if s["name"] in spec.kinds else None
        rows.append(row)
    unknown = sorted(set(spec.kinds) - {s["name"] for s in inputs}) if spec else []
    notes = list(spec.notes) if spec else []
    if args.json:
        _print_json({"object": args.object, "modifier": args.modifier, "inputs": rows, "spec_unknown": unknown, "spec_notes": notes, "part_names": names, "provenance_error": session.provenance_error})
        return 0
    for r in rows:
        rng = f"[{r['min']:g}, {r['max']:g}]" if "min" in r and "max" in r else ", ".join(map(str, r.get("options", [])))
        extra = f"  fixed at the file's value ({r['why_fixed']})" if r["fixed"] else ""
        if r.get("spec"):
            extra += f"  spec: {r['spec']}"
        print(f"{r['name']:<32} {r['type']:<6} value {r['value']!s:<10} default {r.get('default')!s:<8} {rng}{extra}")
    if unknown:
        print(f"the spec names inputs the modifier lacks: {', '.join(unknown)}")
    for note in notes:
        print(f"params spec: {note}", file=sys.stderr)
    if names:
        shown = ", ".join(names[:MAX_NAMES]) + (f" and {len(names) - MAX_NAMES} more" if len(names) > MAX_NAMES else "")
        print(f"the node tree names parts: {shown} (proctex parts shows which)")
    n = sum(r["fixed"] for r in rows)
    print(f"{len(rows)} inputs; {len(rows) - n} vary, {n} held at the file's values" + (" (give ranges with --params-spec or [source.params] to vary them)" if n else ""))
    return 0


def cmd_parts(args: argparse.Namespace) -> int:
    """The parts of a ``.blend`` model's shape and what its node tree calls them: per part its
    name, the other names its faces carry, its share of the area and the nodes that made it; per
    producing node the name it gave and the labels passed over (defaults, computations); and the
    share of the area whose faces have a producer. Evaluated at the file's values, or ``--params``."""
    from proctex.geometry.parts import connected_parts
    from proctex.geometry.surface import triangle_areas
    from proctex.sources.blender import BlenderModel

    if not args.blend.lower().endswith(".blend"):
        return family_parts_command(args)
    given = [f"--{k.replace('_', '-')}" for k in ("prompt", "look", "assign", "png") if getattr(args, k) is not None] + (["--save"] if args.save else [])
    if given:
        raise ValueError(f"{', '.join(given)} read a family, not a .blend file")
    if not args.object:
        raise ValueError("a .blend file needs --object (the object carrying the Geometry Nodes modifier; proctex inputs lists them)")
    if not os.path.isfile(args.blend):
        raise ValueError(f"no such file: {args.blend}")
    try:
        params = json.loads(args.params) if args.params else {}
    except json.JSONDecodeError as exc:
        raise ValueError(f"--params is not valid JSON ({exc})") from exc
    if not isinstance(params, dict):
        raise ValueError(f"--params must be a JSON object of input values, got {type(params).__name__}")
    model = BlenderModel(args.blend, args.object, args.modifier, parts=args.parts_attribute)
    try:
        shape = model.generate(params)  # missing inputs: the file's values
        named = model.last_names
        face_part, _, count = connected_parts(shape.faces, shape.n_vertices)
        areas = triangle_areas(shape.vertices, shape.faces)
        total = float(areas.sum()) or 1.0
        part_area = np.bincount(face_part, weights=areas, minlength=count)
        producers = [{"id": n.id, "name": n.name, "from": n.where, "node": n.node, "dropped": [list(d) for d in n.dropped]} for n in model.producer_names.values()]
        parts = [{"part": i, "name": named.names[i] if named else "", "others": named.others[i] if named else [], "area_share": round(float(part_area[i] / total), 4)} for i in range(count)]
        report = {"object": args.object, "parts": parts, "producers": producers, "covered": named.covered if named else 0.0, "provenance_error": model.session.provenance_error}
    finally:
        model.close()
    if args.json:
        _print_json(report)
        return 0
    for r in parts:
        others = f"  (also {', '.join(r['others'])})" if r["others"] else ""
        print(f"part {r['part']:<4} {r['name'] or '(no name)':<32} {100 * r['area_share']:5.1f} % of the area{others}")
    print("producing nodes:")
    for r in producers:
        dropped = "; passed over: " + ", ".join(f"{lab!r} ({why})" for lab, why in r["dropped"]) if r["dropped"] else ""
        print(f"  {r['id']:<4} {r['node']:<48} -> {r['name'] or '(no name)'}" + (f" from its {r['from']}" if r["name"] else "") + dropped)
    print(f"{100 * report['covered']:.1f} % of the area has a producing node" + (f"; provenance unavailable: {report['provenance_error']}" if report["provenance_error"] else ""))
    return 0


def parse_assign(text: str | None) -> dict[str, str]:
    """``--assign``: ``"3=legs,5=rest"`` or a JSON object ``{"3": "legs"}`` -> ``{"3": "legs"}`` (an
    empty word kept: it clears a stored one). ``ValueError`` for anything else."""
    if not text:
        return {}
    if text.lstrip().startswith("{"):
        return json_strings(text, "--assign", '{"3": "legs"}')
    out = {}
    for item in text.split(","):
        if item.strip():
            key, eq, word = item.partition("=")
            if not eq:
                raise ValueError(f"--assign takes GROUP=WORD pairs separated by commas, e.g. '3=legs,5=rest'; got {item.strip()[:40]!r}")
            out[key.strip()] = word.strip()
    return out


def family_parts_command(args: argparse.Namespace) -> int:
    """``proctex parts FAMILY``: which group took which word (``--png`` draws it), ``--assign`` /
    ``--save`` the user's words."""
    from proctex.looks import family_parts
    from proctex.store.layout import FamilyStore
    from proctex.store.partwords import save_part_words
    from proctex.texture.partsview import parts_picture

    if args.object or args.params or args.parts_attribute:
        raise ValueError("--object, --params and --parts-attribute read a .blend file, not a family")
    if args.png is not None and not args.png.lower().endswith(".png"):
        raise ValueError(f"--png must name a .png file, got {args.png!r}")
    if not isinstance(args.size, int) or not 64 <= args.size <= 2048:
        raise ValueError(f"--size must be in [64, 2048], got {args.size}")
    assign = parse_assign(args.assign)
    if args.save and not assign:
        raise ValueError("--save stores the words of --assign: give them")
    if not os.path.isdir(args.blend) and "://" not in args.blend:
        raise ValueError(f"no such family: {args.blend} (a folder a build wrote, or a .blend file)")
    store = FamilyStore(args.blend)
    shown = {k: v for k, v in assign.items() if v.strip()}
    report, (vertices, faces, face_group) = family_parts(store, args.prompt, args.look, shown)
    if args.save:
        report["stored"] = save_part_words(store, assign, len(report["groups"]))
    if args.png:
        import io

        from proctex.fileio import atomic_write

        buf = io.BytesIO()
        parts_picture(vertices, faces, face_group, report, report["up"], args.size).save(buf, format="PNG", optimize=True)
        atomic_write(args.png, buf.getvalue())
    if args.json:
        _print_json(report)
        return 0
    print(f"{report['family']} (look {report['look']}): prompt {report['prompt']!r}" + (f", read for {report['kind']}" if report["kind"] else ""))
    for row in report["groups"]:
        score = f"{row['score']:.2f}" if isinstance(row["score"], (int, float)) else "    "
        ev = row["evidence"] or {}
        facts = f"{ev.get('members', '?')}x {ev.get('form', '')}, {100 * ev.get('area_share', 0):.0f} % area, height {ev.get('height', ['?', '?'])}" if ev else "(not measured)"
        looks = ", ".join(f"{w} {s:.2f}" for w, s in row["looks_like"])
        print(
            f"group {row['group']:<3} {(row['word'] or '-')[:20]:<20} {row['how']:<6} {score}  {row['text'][:40]!r:<44} {facts}"
            + (f"; looks like {looks}" if looks else "")
            + (f"; rival {row['rival'][0]} {row['rival'][1]:.2f}" if row["rival"] else "")
        )
    for note in report["notes"]:
        print(f"  {note}")
    if report["stored"]:
        print("stored words: " + ", ".join(f"{k}={v}" for k, v in report["stored"].items()) + (" (saved now)" if args.save else ""))
    if args.png:
        print(f"picture: {args.png}")
    return 0


def cmd_transfer(args: argparse.Namespace) -> int:
    from proctex.serve.service import FamilyService
    from proctex.store.layout import FamilyStore
    from proctex.store.state import stored_config
    from proctex.transfer.apply import check_transfer_args

    check_transfer_args(args.seed, args.bake or None)  # nonsense refused before anything is read
    if args.bake < 0:
        raise ValueError(f"--bake must be 0 (the template's textures) or a size in texels, got {args.bake}")
    store = FamilyStore(args.family)
    config = stored_config(store)
    if bool(args.params) == bool(args.mesh):
        raise ValueError("give exactly one of --params JSON or --mesh FILE")
    if args.params:
        if config.shapes().model is None:
            raise ValueError("this family comes from a folder of meshes: transfer a --mesh")
        try:
            params = json.loads(args.params)
        except json.JSONDecodeError as exc:
            raise ValueError(f"--params is not valid JSON ({exc})") from exc
        if not isinstance(params, dict):
            raise ValueError(f"--params must be a JSON object of parameter values, got {type(params).__name__}")
        shape = config.procedural_model().generate(params)
    else:
        shape, _ = load_mesh(args.mesh)
    if not args.out.endswith(".glb"):
        raise ValueError("--out must name a .glb file")
    _check_preview_path(args.preview)
    check_output_file(args.out, args.force)
    check_output_file(args.preview, args.force, "--preview")
    if args.preview and os.path.abspath(args.preview) == os.path.abspath(args.out):
        raise ValueError("--preview and --out name the same file")
    t0 = time.perf_counter()
    svc = FamilyService(store, mapper=args.mapper, device=args.device, look=args.look)
    t1 = time.perf_counter()
    answer, _ = svc.textured(shape, seed=args.seed, bake_size=args.bake or None)
    from proctex.fileio import atomic_write, encode_png
    from proctex.transfer.apply import info

    result = answer.result
    summary = {**info(result), "load_seconds": round(t1 - t0, 3), "mapper": type(svc.mapper).__name__, "look": svc.look.name, "out": args.out, "bytes": len(answer.data)}
    preview = None
    if args.preview:  # rendered before anything is written: a failing preview leaves no GLB behind
        from proctex.texture.render import render_three_quarter

        preview = encode_png(render_three_quarter(shape.vertices, shape.faces, answer.corner_uv, answer.face_group, answer.textures, up=config.up_axis(), size=512, maps=answer.pbr))
        summary["preview"] = args.preview
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    atomic_write(args.out, answer.data)
    if preview is not None:
        Path(args.preview).parent.mkdir(parents=True, exist_ok=True)
        atomic_write(args.preview, preview)
    if args.json:
        _print_json(summary)
    else:
        for note in result.notes:
            print(f"note: {note}")
        print(f"transferred {shape.n_faces} faces with {summary['mapper']} in {result.seconds * 1000:.0f} ms (family loaded in {t1 - t0:.1f}s) -> {args.out}")
        if args.preview:
            print(f"wrote {args.preview} (3/4 view, 512x512)")
    return 0


def generate_settings(args: argparse.Namespace):
    """The :class:`proctex.generate.GenerateSettings` of ``proctex generate``'s flags (checked)."""
    from proctex.generate import GenerateSettings

    bounds = {}
    if args.params_bounds:
        try:
            bounds = json.loads(args.params_bounds)
        except (ValueError, RecursionError) as exc:
            raise ValueError(f"--params-bounds is not valid JSON ({str(exc)[:200]})") from None
        if not isinstance(bounds, dict):
            raise ValueError('--params-bounds must be a JSON object, e.g. {"seats": [2, 3]}')
    if args.rows is not None and not os.path.isfile(args.rows):
        raise ValueError(f"--rows {args.rows}: no such file")
    looks = None
    if args.looks is not None:
        looks = tuple(x.strip() for x in args.looks.split(","))
        if not all(looks):
            raise ValueError(f"--looks takes look names separated by commas (or 'all'), got {args.looks[:80]!r}")
    return GenerateSettings(
        args.family,
        args.out,
        n=args.n,
        rows=args.rows,
        seed=args.seed,
        bounds=bounds,
        format=args.format,
        bake=args.bake or None,
        textures=args.textures,
        max_failed=args.max_failed,
        batch_size=args.batch_size,
        device=args.device,
        looks=looks,
        random_looks=args.random_looks,
    ).validate()


def print_generate_summary(args: argparse.Namespace, summary: dict[str, Any]) -> None:
    if args.json:
        _print_json(summary)
    else:
        print(
            f"generated {summary['written']} variants ({summary['done_before']} done before, {summary['failed']} failed) in {summary['seconds']:.1f}s -> {args.out} (manifest: {summary['manifest']})"
        )


def cmd_generate(args: argparse.Namespace) -> int:
    """``proctex generate`` in this process (``workflows.cli`` runs it on Ray Data unless ``--no-ray``)."""
    from proctex.generate import run_in_process

    settings = generate_settings(args)
    log = (lambda *_: None) if args.quiet or args.json else (lambda m: print(m, flush=True))
    print_generate_summary(args, run_in_process(settings, log=log, quiet=args.quiet or args.json))
    return 0


def cmd_edit(args: argparse.Namespace) -> int:
    from proctex.serve.edits import edit_group
    from proctex.store.layout import FamilyStore

    store = FamilyStore(args.family)
    if args.make_maps:
        from proctex.serve.edits import add_material_maps

        if args.group is not None:
            raise ValueError("--make-maps works on every group: leave out --group")
        if args.look:
            raise ValueError("--make-maps works on the build's look (looks added since have their maps): leave out --look")
        made = add_material_maps(store)
        print(f"made PBR maps for {len(made)} group(s)" + (f": {', '.join(map(str, made))}" if made else " (every group had them)"))
        return 0
    if args.group is None:
        raise ValueError("--group is required (a group index or label)")
    if args.logo is not None and not os.path.isfile(args.logo):
        raise ValueError(f"--logo {args.logo}: no such file")
    record = edit_group(
        store,
        args.group,
        hue=args.hue,
        saturation=args.saturation,
        value=args.value,
        logo=args.logo,
        at=_pair(args.at, "--at") or (0.5, 0.5),
        size=_pair(args.size, "--size") or (0.25, 0.25),
        rotation=args.rotation,
        opacity=args.opacity,
        prompt=args.prompt,
        roughness=args.roughness,
        metallic=args.metallic,
        look=args.look,
    )
    look = f" of look {args.look}" if args.look else ""
    print(f"edited group {record['group']}{look}: {', '.join(k for k in record if k != 'group')}; transfers now use it")
    return 0


def _eval_options(args: argparse.Namespace) -> dict[str, Any]:
    """Validated keyword arguments of :func:`proctex.measure.evaluate.evaluate` from the eval flags."""
    from proctex.build.plan import default_workers
    from proctex.transfer.methods import method_names

    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    known = method_names(aliases=True)
    unknown = [m for m in methods if m not in known]
    if unknown or not methods:
        raise ValueError(f"--methods must name some of {', '.join(known)}, got {args.methods!r}")
    if args.limit is not None and args.limit < 1:
        raise ValueError(f"--limit must be >= 1, got {args.limit}")
    if args.workers < 0:
        raise ValueError(f"--workers must be >= 0 (0: one per CPU, at most 4), got {args.workers}")
    if args.lpips and not os.path.isfile(args.lpips):
        raise ValueError(f"--lpips {args.lpips!r}: no such weights file")
    if args.tracked < 10 or args.tracked > 1_000_000:
        raise ValueError(f"--tracked must be in [10, 1000000], got {args.tracked}")
    return {
        "methods": methods,
        "split": args.shapes,
        "limit": args.limit,
        "lpips": args.lpips,
        "truth": args.truth,
        "tracked": args.tracked,
        "workers": args.workers or default_workers(),
        "quiet": args.quiet or args.json,
    }


def run_eval(store: Any, args: argparse.Namespace, options: dict[str, Any]) -> int:
    """Evaluate, write ``metrics.json`` into the store, print the table (or the JSON)."""
    from proctex.measure.evaluate import evaluate, markdown_table
    from proctex.store.layout import StoreLayout
    from proctex.store.looks import resolve_look

    if not store.exists(StoreLayout.MODELS) and {"corrnet", "corrnet_all"} & set(options["methods"]):
        raise ValueError(f"{store.uri}: no trained models (run the train stage, or evaluate without corrnet)")
    log = (lambda *_: None) if (args.quiet or args.json) else (lambda m: print(m, flush=True))
    look = getattr(args, "look", None)
    metrics = evaluate(store, log=log, look=look, **options)
    if look is None or resolve_look(store, look).built:
        store.write_json(StoreLayout.METRICS, metrics)
    else:  # another look's figures beside its textures; the family's metrics.json stays the build's look's
        store.write_json(resolve_look(store, look).file(StoreLayout.METRICS), metrics)
    if args.json:
        _print_json(metrics)
    else:
        print(markdown_table(metrics))
    return 0


def cmd_eval(args: argparse.Namespace) -> int:
    from proctex.store.layout import FamilyStore
    from proctex.store.state import stored_config

    store = FamilyStore(args.family)
    stored_config(store)  # a clear error when the folder is not a family
    return run_eval(store, args, _eval_options(args))


def cmd_eval_folder(args: argparse.Namespace) -> int:
    """Build a family from a folder of samples (train/ and inference/), then evaluate it."""
    from proctex.build.pipeline import build
    from proctex.store.config import BuildConfig
    from proctex.store.layout import FamilyStore

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
    return {
        "model": args.model,
        "prompt": args.prompt,
        "group_prompts": _group_prompts(args.group_prompts),
        "seed": args.seed,
        "n_train": args.n_train,
        "n_test": args.n_test,
        "rows": args.rows,
        "per_row": args.per_row,
        "frames": args.frames,
        "fresh": args.fresh,
        "quiet": args.quiet,
    }


def print_demo_outputs(result: Any) -> None:
    s = result.summary
    fam = Path(result.out) / "families" / s["model"]
    print(f"demo done in {s['total_seconds']:.0f}s ({len(result.variants)} variants, median transfer {1000 * s['transfer_median_seconds']:.0f} ms). Look at:")
    for what, where in (
        ("report", result.report),
        ("contact sheet", result.contact_sheet),
        ("turntable", result.turntable),
        ("variants", f"{Path(result.out) / 'variants'}/ ({len(result.variants)} GLBs)"),
        ("family store", fam),
        ("studio", f"proctex serve {fam.parent}  ->  http://127.0.0.1:8000/"),
    ):
        print(f"  {what:<14}{where}")


def cmd_demo(args: argparse.Namespace) -> int:
    """The main job in this process (the installed ``proctex demo`` builds on a local Ray instead)."""
    from proctex.demo import run_demo

    log = (lambda *_: None) if args.quiet else (lambda m: print(m, flush=True))
    print_demo_outputs(run_demo(args.out, log=log, **demo_arguments(args)))
    return 0


def cmd_sheet(args: argparse.Namespace) -> int:
    """Sweep, transfer and render a built family's unseen settings (:func:`proctex.demo.finish_demo`)."""
    from proctex.demo import finish_demo
    from proctex.store.layout import FamilyStore
    from proctex.store.state import FamilyState

    if args.rows < 0 or args.per_row < 1 or args.frames < 1 or not 32 <= args.size <= 2048:
        raise ValueError("--rows must be >= 0, --per-row >= 1, --frames >= 1 and --size within 32..2048")
    if not os.path.isdir(args.family):
        raise ValueError(f"{args.family}: no such folder")
    store = FamilyStore(args.family)
    state = FamilyState.load(store)
    state.build_config(store.uri)  # a clear error when the folder is not a family
    missing = [s for s in ("template", "paint") if not state.done(s)]
    if missing:
        raise ValueError(f"{args.family}: the family is not built yet (stages not done: {', '.join(missing)}); run proctex build first")
    if args.look is not None:
        from proctex.store.looks import resolve_look

        resolve_look(store, args.look)  # an unknown look is said before anything is written
    out = args.out or os.path.join("out", "sheets", Path(os.path.abspath(args.family)).name)
    log = (lambda *_: None) if args.quiet else (lambda m: print(m, flush=True))
    result = finish_demo(out, args.family, {}, rows=args.rows, per_row=args.per_row, frames=args.frames, size=args.size, gif_size=args.size, seed=args.seed, log=log, quiet=args.quiet, look=args.look)
    for what, where in (
        ("contact sheet", result.contact_sheet),
        ("turntable", result.turntable),
        ("report", result.report),
        ("variants", f"{Path(result.out) / 'variants'}/ ({len(result.variants)} GLBs)"),
    ):
        print(f"  {what:<14}{where}")
    return 0
