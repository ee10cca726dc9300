"""The house's aesthetics figures (issue 55), counted from the source: what a restructuring must not
make worse.

- imports of the project's own modules inside functions in ``proctex/`` (deferred imports hide a
  module's real dependencies; 268 at 7c5c1d7);
- the largest modules, classes and functions by lines (``proctex``, ``workers``, ``workflows``);
- private names imported across units (the rule ``tests/test_architecture.py`` enforces: 0).

    .venv/bin/python tests/bench/house_figures.py [--json out.json] [--top 8]
"""

from __future__ import annotations

import argparse
import ast
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
PACKAGES = ("proctex", "workers", "workflows")


def function_level_imports(tree: ast.AST, own: tuple[str, ...] = PACKAGES) -> int:
    """How many ``import``/``from ... import`` statements inside a function body of ``tree`` name a
    module of ``own`` (relative imports count as own)."""
    count = 0

    def visit(node: ast.AST, in_function: bool) -> None:
        nonlocal count
        for child in ast.iter_child_nodes(node):
            inside = in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            if in_function and isinstance(child, ast.ImportFrom):
                if child.level or (child.module or "").split(".")[0] in own:
                    count += 1
            elif in_function and isinstance(child, ast.Import):
                if any(a.name.split(".")[0] in own for a in child.names):
                    count += 1
            visit(child, inside)

    visit(tree, False)
    return count


def definitions(tree: ast.AST, module: str) -> list[tuple[str, str, int]]:
    """``(kind, qualified name, lines)`` of every class and top-level or method function in ``tree``."""
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ClassDef):
            out.append(("class", f"{module}.{node.name}", node.end_lineno - node.lineno + 1))
            for item in node.body:
                if isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    out.append(("function", f"{module}.{node.name}.{item.name}", item.end_lineno - item.lineno + 1))
    for node in getattr(tree, "body", []):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            out.append(("function", f"{module}.{node.name}", node.end_lineno - node.lineno + 1))
    return out


def figures(root: Path = ROOT, top: int = 8) -> dict:
    """The figures of the tree at ``root`` (see the module docstring)."""
    from tests.test_architecture import LAYERS, private_imports

    modules, defs, deferred = [], [], 0
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            if "node_modules" in path.parts:
                continue
            text = path.read_text()
            tree = ast.parse(text, str(path))
            rel = path.relative_to(root).as_posix()
            modules.append((rel, text.count("\n") + (not text.endswith("\n") and bool(text))))
            defs += definitions(tree, rel[:-3].replace("/", "."))
            if package == "proctex":
                deferred += function_level_imports(tree)
    modules.sort(key=lambda t: -t[1])
    classes = sorted((d for d in defs if d[0] == "class"), key=lambda d: -d[2])
    functions = sorted((d for d in defs if d[0] == "function"), key=lambda d: -d[2])
    return {
        "function_level_imports_in_proctex": deferred,
        "largest_modules": [{"module": m, "lines": n} for m, n in modules[:top]],
        "largest_classes": [{"class": n, "lines": k} for _, n, k in classes[:top]],
        "largest_functions": [{"function": n, "lines": k} for _, n, k in functions[:top]],
        "private_imports_across_units": private_imports(root / "proctex", LAYERS),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", help="also write the figures here")
    ap.add_argument("--top", type=int, default=8)
    args = ap.parse_args(argv)
    f = figures(top=args.top)
    print(f"imports of own modules inside functions in proctex/: {f['function_level_imports_in_proctex']}")
    print(f"private names imported across units: {len(f['private_imports_across_units'])}")
    for key, name in (("largest_modules", "module"), ("largest_classes", "class"), ("largest_functions", "function")):
        print(f"{key.replace('_', ' ')}:")
        for row in f[key]:
            print(f"  {row['lines']:5d}  {row[name]}")
    if args.json:
        Path(args.json).write_text(json.dumps(f, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
