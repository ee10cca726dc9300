"""``proctex look add|list|rm``: a family's looks (:mod:`proctex.store.looks`): a new prompt, photos
(``--image``), the template GLB painted elsewhere or a textured member (``--from``), painted on the
built family in seconds."""

from __future__ import annotations

import argparse
import os

from .common import _group_prompts, _print_json


def cmd_look(args: argparse.Namespace) -> int:
    from proctex.looks import add_look, remove_look
    from proctex.store.layout import FamilyStore
    from proctex.store.looks import look_summary, looks, new_look_paint
    from proctex.store.state import FamilyState

    store = FamilyStore(args.family)
    state = FamilyState.load(store)
    config = state.build_config(store.uri)
    log = (lambda *_: None) if args.json else print
    if args.action == "add" and args.from_glb:
        paint, glb, member = glb_args(args, config.paint)
        record = add_look(store, args.name, paint, force=args.force, log=log, glb=glb, member=member, limits=look_limits(args))
        if args.json:
            _print_json({"family": store.uri, "look": record})
        return 0
    if args.action == "add" and (args.params is not None or args.member):
        raise ValueError("--params and --member go with --from MEMBER.glb")
    if args.action == "add":
        images, photos = photo_args(args)
        if not images and (not args.prompt or not args.prompt.strip()):
            raise ValueError("look add needs --prompt, --image, or both")
        if args.prompt is not None and not args.prompt.strip():
            raise ValueError("--prompt is empty")
        paint = new_look_paint(config.paint, args.prompt, _group_prompts(args.group_prompts), args.painter, args.texture_size, images=images)
        record = add_look(store, args.name, paint, force=args.force, log=log, photos=photos, limits=look_limits(args))
        if args.json:
            _print_json({"family": store.uri, "look": record})
        return 0
    if args.action == "rm":
        remove_look(store, args.name)
        if not args.json:
            print(f"look {args.name} removed")
        else:
            _print_json({"family": store.uri, "removed": args.name})
        return 0
    rows = [look_summary(store, lk, config.paint) for lk in looks(store)]
    if args.json:
        _print_json({"family": store.uri, "looks": rows})
        return 0
    width = max(len(r["name"]) for r in rows)
    for r in rows:
        made = "built" if r["built"] else f"added {r.get('made', '?')} ({r.get('seconds', 0):.1f} s)"
        print(f"{r['name']:<{width}}  {r['painter']:<9} {r['texture_size']:>5}px  {r['edits']} edits  {made}  {r['prompt']!r}")
    return 0


#: the largest GLB ``look add --from`` reads.
MAX_GLB_BYTES = 512 * 2**20


def read_glb_file(path: str) -> bytes:
    """A GLB file's bytes, its size checked first (:data:`MAX_GLB_BYTES`); ``ValueError`` naming it."""
    try:
        size = os.path.getsize(path)
    except OSError as exc:
        raise ValueError(f"cannot read {path!r}: {exc.strerror or exc}") from None
    if size > MAX_GLB_BYTES:
        raise ValueError(f"{path!r} has {size:,} bytes, over the limit of {MAX_GLB_BYTES:,}")
    with open(path, "rb") as fh:
        return fh.read()


def glb_args(args: argparse.Namespace, build_paint) -> tuple:
    """``--from FILE.glb`` (with ``--params JSON`` or ``--member``: a textured member) -> the look's
    paint settings and either the repainted template's bytes or the member ``{"glb", "params"}``."""
    import json

    from proctex.store.layout import digest
    from proctex.store.looks import new_look_paint

    if args.image or args.prompt or args.group_prompts:
        raise ValueError("--from reads a look from a GLB: it takes no --prompt, --image or --group-prompts")
    data = read_glb_file(args.from_glb)
    member = None
    if args.params is not None or args.member:
        params = None
        if args.params is not None:
            try:
                params = json.loads(args.params)
            except (json.JSONDecodeError, RecursionError) as exc:
                raise ValueError(f"--params is not valid JSON ({str(exc)[:200]})") from None
            if not isinstance(params, dict):
                raise ValueError(f"--params must be a JSON object of parameter values, got {type(params).__name__}")
        member = {"glb": data, "params": params}
    paint = new_look_paint(build_paint, None, texture_size=args.texture_size, glb={"name": os.path.basename(args.from_glb)[:200], "sha256": digest(data)})
    return paint, (None if member else data), member


def _pairs(items: list[str] | None, flag: str) -> dict[str, str]:
    """``PART=VALUE`` items of a repeated flag (``PART`` a group number, label or part word, or ``*``
    for the photo of the rest) -> {part: value}; a part given twice is an error."""
    out: dict[str, str] = {}
    for item in items or []:
        part, sep, value = item.partition("=")
        if not sep or not part.strip() or not value.strip():
            raise ValueError(f"{flag} takes PART=VALUE (PART a group number, label or part word), got {item[:80]!r}")
        part = part.strip()
        if part in out:
            raise ValueError(f"{flag} names {part[:40]!r} twice")
        out[part] = value.strip()
    return out


def photo_args(args: argparse.Namespace) -> tuple[dict[str, dict], dict]:
    """``--image [PART=]FILE`` (repeated), ``--image-scale PART=LENGTH``, ``--image-rotate PART=DEG``,
    ``--units``, ``--normal-strength``, ``--roughness-strength`` -> the look's ``images`` entries and
    each photo read (:func:`proctex.texture.exemplar.read_photo`: refused before anything is painted
    or written). A FILE without ``PART=`` (an existing file's whole name) is the photo of every group
    the prompt does not name (with no ``--prompt``: every group no other photo has)."""
    import os

    from proctex.texture.photo import parse_length, read_photo

    files: dict[str, str] = {}
    for item in args.image or []:
        if os.path.isfile(item) or "=" not in item:
            key, path = "*", item
        else:
            key, _, path = item.partition("=")
            key, path = key.strip(), path.strip()
            if not key or not path:
                raise ValueError(f"--image takes [PART=]FILE, got {item[:80]!r}")
        if key in files:
            raise ValueError("--image gives the photo of the rest twice" if key == "*" else f"--image names {key[:40]!r} twice")
        files[key] = path
    scales, turns = _pairs(args.image_scale, "--image-scale"), _pairs(args.image_rotate, "--image-rotate")
    for flag, given in (("--image-scale", scales), ("--image-rotate", turns)):
        unknown = sorted(set(given) - set(files))
        if unknown:
            raise ValueError(f"{flag} names {', '.join(repr(u[:40]) for u in unknown)}, which no --image gives a photo")
    images: dict[str, dict] = {}
    photos = {}
    for key, path in files.items():
        photos[key] = read_photo(path)
        entry = {"file": path, "scale": parse_length(scales[key], args.units) if key in scales else None, "units": args.units, "normal": args.normal_strength, "roughness": args.roughness_strength}
        if key in turns:
            try:
                entry["rotate"] = float(turns[key])
            except ValueError:
                raise ValueError(f"--image-rotate {key[:40]}= takes degrees, got {turns[key][:40]!r}") from None
        if key == "*":
            entry["under_prompt"] = args.prompt is not None
        images[key] = entry
    return images, photos


def add_look_parser(sub: argparse._SubParsersAction, painters: list[str], painter_help: str) -> None:
    p = sub.add_parser("look", help="a family's looks: paint a built family with another prompt in seconds (no rebuild), list or remove them")
    acts = p.add_subparsers(dest="action", required=True)
    a = acts.add_parser("add", help="paint a new look: the stored template, grouping and UVs with another prompt")
    a.add_argument("family")
    a.add_argument("name", help="the look's name (letters, digits, '.', '_', '-')")
    a.add_argument("--prompt", help="the look's words (optional with --image: then the build's prompt covers what no photo does)")
    a.add_argument(
        "--from",
        dest="from_glb",
        metavar="FILE.glb",
        help="a look from the family's template GLB painted elsewhere (Blender, Substance, ...): its textures "
        "resampled into the template's atlases; faces matched by position and UV. With --params or --member: "
        "any textured member of the family, in any UVs",
    )
    a.add_argument("--params", help="with --from: the member's parameters (JSON): the family's own shape for them")
    a.add_argument("--member", action="store_true", help="with --from: a textured member of the family without its parameters")
    a.add_argument(
        "--image",
        action="append",
        metavar="[PART=]FILE",
        help="a photo synthesised on PART (a group number, part name or part word; repeat for more); a FILE alone covers every group the prompt does not name (PNG, JPEG, WebP, TIFF, BMP, TGA)",
    )
    a.add_argument("--image-scale", action="append", metavar="PART=LENGTH", help="how much surface the photo's width spans: 0.5 (family units), 50cm, 2in (default: half the part's longest side)")
    a.add_argument("--image-rotate", action="append", metavar="PART=DEGREES", help="turn the photo against the part's long axis (default 0: the photo's width along it)")
    a.add_argument("--units", default="m", choices=["m", "cm", "mm", "in", "ft"], help="the family's units (default m)")
    a.add_argument("--normal-strength", type=float, default=1.0, help="relief from the photos: 0 flat, 1 default, up to 10")
    a.add_argument("--roughness-strength", type=float, default=1.0, help="how far the photos' local contrast moves the prompt's roughness: 0 not at all, 1 default, up to 10")
    a.add_argument("--group-prompts", help="JSON (inline or a file) overriding the prompt per group label or index")
    a.add_argument("--painter", choices=painters, help=f"default: the build's painter; {painter_help}")
    a.add_argument("--texture-size", type=int, help="default: the build's")
    a.add_argument("--force", action="store_true", help="replace a look of that name")
    a.add_argument("--max-seconds", type=float, help="stop painting past this (default 600; nothing is written)")
    a.add_argument("--max-looks", type=int, help="looks the family may hold, the build's not counted (default 64)")
    a.add_argument("--json", action="store_true")
    ls = acts.add_parser("list", help="the family's looks")
    ls.add_argument("family")
    ls.add_argument("--json", action="store_true")
    rm = acts.add_parser("rm", help="remove a look (not the build's)")
    rm.add_argument("family")
    rm.add_argument("name")
    rm.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_look)


def look_limits(args):
    """:class:`proctex.looks.LookLimits` with ``--max-seconds`` and ``--max-looks`` over its defaults."""
    from dataclasses import replace

    from proctex.looks import LookLimits

    over = {k: v for k, v in (("seconds", args.max_seconds), ("looks", args.max_looks)) if v is not None}
    return replace(LookLimits(), **over)
