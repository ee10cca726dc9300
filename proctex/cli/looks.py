"""``proctex look add|list|rm``: a family's looks (:mod:`proctex.store.looks`), a new prompt painted
on the built family in seconds."""

from __future__ import annotations

import argparse

from .common import _group_prompts, _print_json


def cmd_look(args: argparse.Namespace) -> int:
    from proctex.build.looks import add_look, remove_look
    from proctex.store.layout import FamilyStore
    from proctex.store.looks import look_summary, looks, new_look_paint
    from proctex.store.state import FamilyState

    store = FamilyStore(args.family)
    state = FamilyState.load(store)
    config = state.build_config(store.uri)
    if args.action == "add":
        if not args.prompt or not args.prompt.strip():
            raise ValueError("look add needs --prompt")
        paint = new_look_paint(config.paint, args.prompt, _group_prompts(args.group_prompts), args.painter, args.texture_size)
        record = add_look(store, args.name, paint, force=args.force, log=(lambda *_: None) if args.json else print)
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


def add_look_parser(sub: argparse._SubParsersAction, painters: list[str], painter_help: str) -> None:
    p = sub.add_parser("look", help="a family's looks: paint a built family with another prompt in seconds (no rebuild), list or remove them")
    acts = p.add_subparsers(dest="action", required=True)
    a = acts.add_parser("add", help="paint a new look: the stored template, grouping and UVs with another prompt")
    a.add_argument("family")
    a.add_argument("name", help="the look's name (letters, digits, '.', '_', '-')")
    a.add_argument("--prompt", required=True)
    a.add_argument("--group-prompts", help='JSON (inline or a file) overriding the prompt per group label or index')
    a.add_argument("--painter", choices=painters, help=f"default: the build's painter; {painter_help}")
    a.add_argument("--texture-size", type=int, help="default: the build's")
    a.add_argument("--force", action="store_true", help="replace a look of that name")
    a.add_argument("--json", action="store_true")
    ls = acts.add_parser("list", help="the family's looks")
    ls.add_argument("family")
    ls.add_argument("--json", action="store_true")
    rm = acts.add_parser("rm", help="remove a look (not the build's)")
    rm.add_argument("family")
    rm.add_argument("name")
    rm.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_look)
