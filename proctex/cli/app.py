"""The ``proctex`` command line.

Every command validates its input and answers bad input with ``error: ...`` on stderr and exit
status 2, without writing partial output.
"""

from __future__ import annotations

import argparse
import os
import sys

from proctex.store.config import PRESETS
from proctex.texture.painting import painter_help, painter_names
from proctex.transfer.methods import method_help, method_names

from .families import (
    cmd_build,
    cmd_demo,
    cmd_edit,
    cmd_eval,
    cmd_eval_folder,
    cmd_gallery,
    cmd_generate,
    cmd_inputs,
    cmd_parts,
    cmd_sheet,
    cmd_transfer,
)
from .looks import add_look_parser
from .shapes import (
    cmd_correspond,
    cmd_match,
    cmd_models,
    cmd_paint,
    cmd_render,
    cmd_sample,
    cmd_segment,
    cmd_template,
)


def _add_eval_flags(p: argparse.ArgumentParser) -> None:
    from proctex.measure.evaluate import default_methods
    from proctex.store.config import TRUTHS

    p.add_argument("--shapes", choices=["test", "train"], default="test")
    p.add_argument("--methods", default=",".join(default_methods()), help=f"comma-separated correspondence methods (default: {','.join(default_methods())}): {method_help()}")
    p.add_argument("--limit", type=int, help="evaluate only the first N shapes")
    p.add_argument("--lpips", help="a local LPIPS (AlexNet) weights file: adds LPIPS to SSIM and PSNR")
    p.add_argument("--workers", type=int, default=0, help="processes evaluating shapes in parallel (0: one per CPU, at most 4)")
    p.add_argument(
        "--truth",
        choices=list(TRUTHS),
        default="auto",
        help="ground truth: auto (the config's; canonical coordinates for built-in models), vertex-index (the samples share one "
        "vertex order), canonical, or none (points tracked by the cage solver, no GT error)",
    )
    p.add_argument("--tracked", type=int, default=5000, help="tracked template points and truth samples per shape (vertex-index: every vertex)")
    p.add_argument("--json", action="store_true")
    p.add_argument("--quiet", action="store_true")


# ------------------------------------------------------------------------------------------ main
def build_parser() -> argparse.ArgumentParser:
    from proctex import __version__

    parser = argparse.ArgumentParser(prog="proctex", description="Consistent texturing of procedural shape families.")
    parser.add_argument("--version", action="version", version=f"proctex {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    parser.subparsers = sub  # type: ignore[attr-defined]  # a layer above (workflows.cli) adds its commands and options

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
    p.add_argument("--method", choices=method_names(solver=True), default="cage")
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
    p.add_argument("--group-prompts", help='JSON (inline or a file) overriding the prompt per group label, index or part word, e.g. {"seat": "red velvet"}')
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", required=True)
    p.add_argument("--size", type=int, default=1024, help="texture size per group")
    p.add_argument("--painter", choices=painter_names(), default="surface", help=painter_help())
    p.add_argument("--views", type=int, default=11, help="camera path length for view painters")
    p.add_argument("--view-size", type=int, default=512)
    p.add_argument("--model-dir", help="local diffusers model folder (diffusion painter)")
    p.add_argument("--steps", type=int, default=30, help="diffusion steps")
    p.add_argument("--device", default="cpu")
    p.add_argument("--up", choices=["auto", "x", "y", "z"], default="auto", help="up axis (auto: y for OBJ/glTF files, else z)")
    p.add_argument("--obj", action="store_true", help="also write OBJ + MTL")
    p.add_argument("--occlusion", action="store_true", help="bake ambient occlusion into the PBR maps")
    p.add_argument("--preview", metavar="PNG", help="also write a 512px 3/4 view of the painted template to this .png")
    p.add_argument("--force", action="store_true", help="overwrite an existing --preview")
    p.add_argument("--json", action="store_true")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=cmd_paint)

    p = sub.add_parser("build", help="build a family: sample, template, paint, cage pairs, train (into a store folder)")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--model", help="built-in model name")
    src.add_argument("--folder", help="folder of samples (mesh + JSON params, train/ and inference/)")
    src.add_argument("--blend", metavar="FILE", help="a .blend file whose Geometry Nodes modifier is the model (with --object)")
    p.add_argument("--object", help="--blend: the object carrying the modifier")
    p.add_argument("--modifier", default="GeometryNodes", help="--blend: the Geometry Nodes modifier's name")
    p.add_argument("--parts-attribute", metavar="NAME", help="--blend: a face / point / corner attribute whose values are the parts")
    p.add_argument("--keep-uv", metavar="UVMAP", help="--blend: keep this UV map of the graph as the template's UVs")
    p.add_argument("--params-spec", metavar="FILE.json", help="the inputs' ranges and conditions from a spec file (nested sp_<name>.json or flat {name: [low, high]})")
    p.add_argument("config_file", nargs="?", metavar="CONFIG", help="JSON or TOML build config (same as --config)")
    p.add_argument("--config", help="JSON or TOML build config, in sections or flat keys (flags override it)")
    p.add_argument("--preset", choices=sorted(PRESETS), help="start from a named config (the config file and flags override it)")
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
    p.add_argument("--device", help="where every torch step runs (cage solver, network training, diffusion painter): cpu, cuda or cuda:<i>")
    p.add_argument("--up", choices=["auto", "x", "y", "z"])
    p.add_argument("--painter", choices=painter_names(), help=f"template painter (default surface): {painter_help()}")
    p.add_argument("--model-dir", help="local diffusers model folder (--painter diffusion)")
    p.add_argument("--tessellation", choices=["adaptive", "fixed"], help="built-in models: segments follow part sizes (adaptive, the default) or fixed counts")
    p.add_argument("--truth", choices=["auto", "canonical", "vertex-index", "none"], help="what the evaluation takes as ground truth (vertex-index: the samples share one vertex order)")
    p.add_argument("--stages", help="comma-separated subset of sample,template,paint,pairs,train,evaluate")
    p.add_argument("--look", help="the name of the look the build paints (default: default); proctex look add paints more")
    p.add_argument("--workers", type=int, default=0, help="in process: processes solving cage pairs side by side (0: one per CPU, at most 4, from 16 pairs on)")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=cmd_build)

    p = sub.add_parser("inputs", help="a .blend modifier's inputs: types, defaults, ranges and which need bounds")
    p.add_argument("blend", metavar="FILE.blend")
    p.add_argument("--object", required=True, help="the object carrying the Geometry Nodes modifier")
    p.add_argument("--modifier", default="GeometryNodes")
    p.add_argument("--params-spec", metavar="FILE.json", help="check a spec file against the inputs (ranges, unknown names)")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_inputs)

    p = sub.add_parser(
        "parts", help="a family's part groups and the part word each took (a PNG and JSON; --assign gives the last word), or a .blend model's parts and the names its node tree gives them"
    )
    p.add_argument("blend", metavar="FAMILY|FILE.blend", help="a built family (folder or URI), or a .blend file")
    p.add_argument("--prompt", help="FAMILY: the prompt to read (default: the look's)")
    p.add_argument("--look", help="FAMILY: the look whose prompt and words to read (default: the build's)")
    p.add_argument(
        "--assign", metavar="G=WORD,...", help="FAMILY: your word per group, e.g. '3=legs,5=rest' or JSON {\"3\": \"legs\"} ('rest': no word; an empty word clears a stored one with --save)"
    )
    p.add_argument("--save", action="store_true", help="FAMILY: store --assign in the family: every look painted afterwards follows it")
    p.add_argument("--png", metavar="FILE.png", help="FAMILY: draw the template, each group with its number, word and score")
    p.add_argument("--size", type=int, default=400, help="FAMILY: --png pixels per view (64-2048)")
    p.add_argument("--object", help="FILE.blend: the object carrying the Geometry Nodes modifier")
    p.add_argument("--modifier", default="GeometryNodes")
    p.add_argument("--params", help="FILE.blend: input values (JSON); the others keep the file's values")
    p.add_argument("--parts-attribute", help="FILE.blend: an attribute whose values are the parts (instead of the mesh's connectivity)")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_parts)

    p = sub.add_parser("transfer", help="texture a new shape of a family: textured GLB")
    p.add_argument("family")
    p.add_argument("--params", help="parameters (JSON) for the family's model")
    p.add_argument("--mesh", help="a mesh file of the family")
    p.add_argument("--out", required=True, help="output .glb")
    p.add_argument("--mapper", choices=method_names(aliases=True), default="auto", help=f"the correspondence method: {method_help()}")
    p.add_argument("--bake", type=int, default=0, help="bake into the shape's own atlas at this size (0: read the template textures)")
    p.add_argument("--device", default="cpu", help="where the networks run: cpu, cuda or cuda:<i>")
    p.add_argument("--preview", metavar="PNG", help="also write a 512px 3/4 view of the textured shape to this .png")
    p.add_argument("--force", action="store_true", help="overwrite an existing --out / --preview")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--look", help="the family's look to texture with (proctex look list; default: the build's)")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_transfer)

    add_look_parser(sub, painter_names(), painter_help())

    p = sub.add_parser("generate", help="textured variants by the thousand: one file per parameter row and a Parquet manifest")
    p.add_argument("family", help="the family store (path or URI)")
    rows = p.add_mutually_exclusive_group(required=True)
    rows.add_argument("--n", type=int, help="parameter rows to sample (Latin hypercube over the family's space)")
    rows.add_argument("--rows", metavar="FILE", help="a Parquet or CSV file of parameter rows (one column per parameter)")
    p.add_argument("--out", required=True, help="output folder or URI (variants/, records/, manifest.parquet); a rerun resumes")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--params-bounds", metavar="JSON", help='narrow the sampled ranges, e.g. {"seats": [2, 3]}')
    p.add_argument("--format", choices=["glb", "obj"], default="glb")
    p.add_argument("--bake", type=int, default=0, help="give each variant its own atlas at this size (0: the template's textures)")
    p.add_argument(
        "--textures", choices=["embedded", "shared"], default="embedded", help="embedded: every GLB carries its textures and PBR maps; shared: written once into textures/, each GLB refers to them"
    )
    p.add_argument(
        "--looks", metavar="NAMES", help="the family's looks to make every shape in, e.g. walnut,oak (or 'all'; default: the build's look); a --rows file's 'look' column names a row's look instead"
    )
    p.add_argument("--random-looks", type=int, default=0, metavar="N", help="first add N looks painted from prompts sampled from the painter's vocabulary (seeded by --seed), then use them too")
    p.add_argument("--max-failed", type=int, default=10, help="rows that may fail (recorded in the manifest) before the run stops")
    p.add_argument("--device", default="cpu", help="where the networks run: cpu, cuda or cuda:<i>")
    p.add_argument("--batch-size", type=int, default=8, help="rows per batch")
    p.add_argument("--quiet", action="store_true")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=cmd_generate)

    p = sub.add_parser("render", help="render a textured GLB (e.g. a transfer result) to a PNG, or a turntable GIF")
    p.add_argument("file", metavar="FILE.glb", help="textured .glb (or .gltf) file")
    p.add_argument("--out", help="output .png (or .gif with --views turntable); default: FILE with a .png suffix")
    p.add_argument("--force", action="store_true", help="overwrite an existing output file")
    p.add_argument("--size", type=int, default=512, help="pixels per view (square)")
    p.add_argument(
        "--views", choices=["front", "six", "turntable"], default="front", help="front: one 3/4 view; six: the six canonical views (3x2, labelled); turntable: --frames views around the up axis"
    )
    p.add_argument("--frames", type=int, default=24, help="turntable frames")
    p.add_argument("--fps", type=float, default=12.0, help="turntable GIF frame rate")
    p.add_argument("--up", choices=["auto", "x", "y", "z"], default="auto", help="up axis (auto: y for glTF/OBJ files, else z)")
    p.set_defaults(func=cmd_render)

    p = sub.add_parser("edit", help="edit one group's template texture (re-paint, HSV shift, roughness / metalness, logo); applies to every transfer")
    p.add_argument("family")
    p.add_argument("--group", help="group index or label (required unless --make-maps)")
    p.add_argument("--make-maps", action="store_true", help="give a family painted before PBR maps existed its maps (from its stored prompts)")
    p.add_argument("--prompt", help="re-paint the group with this prompt")
    p.add_argument("--hue", type=float, default=0.0, help="hue shift in degrees")
    p.add_argument("--saturation", type=float, default=1.0, help="saturation scale")
    p.add_argument("--value", type=float, default=1.0, help="value (brightness) scale")
    p.add_argument("--roughness", type=float, help="move the group's roughness map to this mean, in [0, 1]")
    p.add_argument("--metallic", type=float, help="move the group's metalness map to this mean, in [0, 1]")
    p.add_argument("--logo", help="image file to place on the texture")
    p.add_argument("--at", help="UV centre of the image, e.g. 0.5,0.5")
    p.add_argument("--size", help="UV size of the image, e.g. 0.2 or 0.3,0.1")
    p.add_argument("--rotation", type=float, default=0.0)
    p.add_argument("--opacity", type=float, default=1.0)
    p.add_argument("--look", help="the family's look to edit (proctex look list; default: the build's)")
    p.set_defaults(func=cmd_edit)

    p = sub.add_parser("eval", help="measure a built family on its unseen shapes, methods side by side (metrics.json + a table)")
    p.add_argument("family")
    p.add_argument("--look", help="the family's look to measure (its metrics.json goes into the look's folder; default: the build's)")
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

    p = sub.add_parser("sheet", help="contact sheet, turntable, GLBs and report of a built family's unseen settings (built-in, generator or .blend)")
    p.add_argument("family", help="a built family folder")
    p.add_argument("--out", help="where to write (default out/sheets/<family folder name>)")
    p.add_argument("--rows", type=int, default=3, help="parameters swept (those that change the shape most), plus one row of random settings")
    p.add_argument("--per-row", type=int, default=5, help="variants per row")
    p.add_argument("--frames", type=int, default=24, help="turntable frames")
    p.add_argument("--size", type=int, default=320, help="pixels per variant")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--look", help="the family's look to show (proctex look list; default: the build's)")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=cmd_sheet)

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


#: What a command may fail with on bad input or a bad place to write: an ``error: ...`` line, exit 2.
USER_ERRORS = (ValueError, OSError, OverflowError, RecursionError, MemoryError, UnicodeError)


def run(parser: argparse.ArgumentParser, argv: list[str] | None = None) -> int:
    """Parse and run a command. Bad input, an unwritable output or a number too large prints
    ``error: ...`` and returns 2; anything else prints ``error: internal error (Type): ...`` and
    returns 2 too (``PROCTEX_DEBUG=1`` shows the traceback instead). Ctrl-C returns 130."""
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130
    except USER_ERRORS as exc:
        print(f"error: {str(exc)[:2000] or type(exc).__name__}", file=sys.stderr)
        return 2
    except Exception as exc:
        if os.environ.get("PROCTEX_DEBUG"):
            raise
        print(f"error: internal error ({type(exc).__name__}): {str(exc)[:500]}", file=sys.stderr)
        return 2


def main(argv: list[str] | None = None) -> int:
    return run(build_parser(), argv)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
