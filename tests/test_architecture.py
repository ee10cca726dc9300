"""The house rules the code must keep: ``proctex`` imports no module of its own in a circle (at
module level or inside functions) and never imports Ray (docs/architecture.md: Ray lives in ``workers/`` and
``workflows/``)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1] / "proctex"


def module_name(path: Path, root: Path = ROOT) -> str:
    rel = path.relative_to(root.parent).with_suffix("")
    parts = list(rel.parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def package_of(module: str, path: Path) -> str:
    """The package a module's relative imports start from."""
    return module if path.name == "__init__.py" else module.rpartition(".")[0]


def import_target(node: ast.ImportFrom, package: str) -> str:
    """The absolute module a ``from ... import`` names (relative imports resolved from ``package``)."""
    if not node.level:
        return node.module or ""
    base = package.split(".")[: len(package.split(".")) - node.level + 1]
    return ".".join(base + ([node.module] if node.module else []))


def import_graph(root: Path = ROOT) -> tuple[dict[str, set[str]], dict[str, set[str]]]:
    """``(edges, external)``: per module of the package at ``root`` the package modules it imports
    anywhere in its body (functions included; ``from . import x`` counts as importing ``x``, not
    the package), and the top-level names of the outside packages it imports."""
    modules = {module_name(p, root): p for p in root.rglob("*.py")}
    edges: dict[str, set[str]] = {m: set() for m in modules}
    external: dict[str, set[str]] = {m: set() for m in modules}

    def resolve(name: str) -> str | None:
        while name and name not in modules:
            name = name.rpartition(".")[0]
        return name or None

    for mod, path in modules.items():
        package = package_of(mod, path)
        tree = ast.parse(path.read_text(), str(path))
        typing_only = {id(n) for block in ast.walk(tree) if isinstance(block, ast.If) and "TYPE_CHECKING" in ast.unparse(block.test) for n in ast.walk(block)}  # imports for annotations only: not run
        for node in ast.walk(tree):
            if id(node) in typing_only:
                continue
            if isinstance(node, ast.ImportFrom):
                target = import_target(node, package)
                if target.split(".")[0] != root.name:
                    external[mod].add(target.split(".")[0])
                    continue
                subs = [f"{target}.{a.name}" for a in node.names if f"{target}.{a.name}" in modules]
                found = subs if len(subs) == len(node.names) else subs + [resolve(target)]
            elif isinstance(node, ast.Import):
                found = []
                for a in node.names:
                    if a.name.split(".")[0] == root.name:
                        found.append(resolve(a.name))
                    else:
                        external[mod].add(a.name.split(".")[0])
            else:
                continue
            edges[mod].update(f for f in found if f and f != mod)
    return edges, external


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return out


def test_the_cycle_finder_finds_a_circle_through_a_function_level_import(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from .b import f\n")
    (pkg / "b.py").write_text("def f():\n    from .sub import c\n")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "sub" / "c.py").write_text("import numpy\nfrom .. import a\n")
    (pkg / "d.py").write_text("from . import b\nfrom .sub import c\n")
    (pkg / "e.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .f import F\n")
    (pkg / "f.py").write_text("from .e import x\n")
    edges, external = import_graph(pkg)
    assert edges["pkg.d"] == {"pkg.b", "pkg.sub.c"}  # not the packages themselves
    assert edges["pkg.e"] == set() and edges["pkg.f"] == {"pkg.e"}  # TYPE_CHECKING imports never run
    assert cycles(edges) == [["pkg.a", "pkg.b", "pkg.sub.c"]]
    assert external["pkg.sub.c"] == {"numpy"}
    (pkg / "sub" / "c.py").write_text("import numpy\n")
    assert cycles(import_graph(pkg)[0]) == []


def test_proctex_has_no_import_circle():
    found = cycles(import_graph()[0])
    assert not found, "import circles in proctex (function-level imports count): " + "; ".join(" <-> ".join(c) for c in found)


#: The units of ``proctex`` from the bottom up: a module imports its own unit or lower ones only.
#: The folder list reads as the pipeline: shapes come from ``sources``, the family lives in the
#: ``store`` (its typed records), ``transfer`` is the run-time path (records in, textured shapes
#: out), ``measure`` scores it, ``build`` makes a family stage by stage, ``serve`` answers requests
#: on top of records and transfer (never the build), ``generate`` makes variants in bulk.
#: ``_reference`` (for the tests) may import anything and is imported by nothing shipped.
LAYERS = {
    "proctex.fileio": 0,
    "proctex.params": 0,
    "proctex.progress": 0,
    "proctex.plugins": 0,
    "proctex.pools": 0,
    "proctex.torch_kernels": 0,
    "proctex.geometry": 1,
    "proctex.models": 2,
    "proctex.texture": 2,
    "proctex.correspond": 3,
    "proctex.sources": 4,
    "proctex.store": 5,
    "proctex.transfer": 6,
    "proctex.measure": 7,
    "proctex.looks": 8,
    "proctex.build": 9,
    "proctex.serve": 9,
    "proctex.generate": 10,
    "proctex.demo": 11,
    "proctex.cli": 12,
}


def unit_of(module: str, layers: dict[str, int]) -> str | None:
    """The longest prefix of ``module`` in ``layers`` (its unit), or None."""
    best = None
    for unit in layers:
        if (module == unit or module.startswith(unit + ".")) and (best is None or len(unit) > len(best)):
            best = unit
    return best


def upward_imports(edges: dict[str, set[str]], layers: dict[str, int]) -> list[str]:
    """``"a -> b"`` for every import from a unit to another unit of the same or a higher level."""
    bad = []
    for mod, targets in sorted(edges.items()):
        u = unit_of(mod, layers)
        if u is None:
            continue
        for t in sorted(targets):
            v = unit_of(t, layers)
            if v is not None and v != u and layers[v] >= layers[u]:
                bad.append(f"{mod} -> {t}")
    return bad


def test_the_layer_check_finds_an_upward_and_a_sideways_import():
    edges = {"p.low.a": {"p.low.b"}, "p.low.b": {"p.high.c"}, "p.side.d": {"p.mid.e"}, "p.mid.e": {"p.low.a"}, "p.high.c": {"p.mid.e"}}
    layers = {"p.low": 0, "p.mid": 1, "p.side": 1, "p.high": 2}
    assert upward_imports(edges, layers) == ["p.low.b -> p.high.c", "p.side.d -> p.mid.e"]
    edges["p.low.b"] = set()
    edges["p.side.d"] = {"p.low.b"}
    assert upward_imports(edges, layers) == []


def test_every_module_sits_in_a_layer_and_imports_only_downwards():
    edges, _ = import_graph()
    unplaced = sorted(m for m in edges if unit_of(m, LAYERS) is None and m != "proctex" and not m.startswith("proctex._reference"))
    assert not unplaced, f"modules in no layer of LAYERS (place them): {unplaced}"
    bad = upward_imports(edges, LAYERS)
    assert not bad, "imports that go up or sideways between units:\n" + "\n".join(bad)


def test_proctex_never_imports_ray():
    _, external = import_graph()
    offenders = sorted(m for m, names in external.items() if "ray" in names)
    assert not offenders, f"proctex modules importing ray: {offenders}"


#: What runs inside someone else's Python: the Blender add-on (Blender's own interpreter, nothing
#: of ours installed) and the Blender side of a .blend source (``.venv-blender``: bpy and numpy).
FOREIGN = {Path(__file__).resolve().parents[1] / "clients" / "blender" / "proctex_blender": {"bpy", "addon_utils", "mathutils"}, ROOT / "sources" / "blender_server.py": {"bpy", "numpy"}}


def foreign_imports(path: Path, allowed: set[str]) -> list[str]:
    """Imports in ``path`` (a file, or every ``.py`` under a folder) of anything but the standard
    library, the package's own modules and ``allowed``."""
    import sys

    files = [path] if path.is_file() else sorted(path.rglob("*.py"))
    bad = []
    for f in files:
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level:
                continue
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            bad += [f"{f.name}: {n}" for n in names if n.split(".")[0] not in sys.stdlib_module_names and n.split(".")[0] not in allowed and n != "__future__"]
    return bad


def test_code_that_runs_in_blender_imports_only_what_blender_has(tmp_path):
    for path, allowed in FOREIGN.items():
        assert path.exists(), path
        assert not foreign_imports(path, allowed), foreign_imports(path, allowed)
    sneaky = tmp_path / "addon.py"
    sneaky.write_text("import json\nimport bpy\nfrom proctex.geometry import shape\nfrom . import client\n")
    assert foreign_imports(sneaky, {"bpy"}) == ["addon.py: proctex.geometry"]


def test_the_library_never_imports_its_slow_references():
    """The ``*_reference`` implementations are for the tests (``proctex/_reference``): the shipped
    modules read as the product and never call them."""
    edges, _ = import_graph()
    offenders = sorted(m for m, targets in edges.items() if not m.startswith("proctex._reference") and any(t.startswith("proctex._reference") for t in targets))
    assert not offenders, f"shipped modules importing proctex._reference: {offenders}"
    shipped = [p for p in ROOT.rglob("*.py") if "_reference" not in p.parts]
    defined = [f"{module_name(p)}.{n.name}" for p in shipped for n in ast.walk(ast.parse(p.read_text())) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)) and n.name.endswith("_reference")]
    assert not defined, f"reference implementations in shipped modules: {defined}"


STORE_NAMES = ("family.json", "samples.parquet", "pairs.parquet", "metrics.json", "template/", "models/", "meshes/", "correspondences/", "paint.json", "uv.npz", "painted.npz", "grouping.json")


def store_literals(paths) -> list[str]:
    """``file:line: text`` of every string constant (f-strings included) in ``paths`` that spells a
    family-store path (:data:`STORE_NAMES`)."""
    found = []
    for p in paths:
        tree = ast.parse(p.read_text())
        prose = {id(n.value) for n in ast.walk(tree) if isinstance(n, ast.Expr) and isinstance(n.value, ast.Constant)}  # docstrings
        for node in ast.walk(tree):
            if (
                isinstance(node, ast.Constant)
                and isinstance(node.value, str)
                and id(node) not in prose
                and not any(c.isspace() for c in node.value)  # messages and help texts may name files
                and any(n in node.value for n in STORE_NAMES)
            ):
                found.append(f"{p.name}:{node.lineno}: {node.value!r}")
    return found


def test_only_the_store_layout_spells_store_paths(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text('x = f"models/group_{3}.pt"\ny = "samples.parquet"\n"""Docstring naming family.json."""\nraise ValueError("no family.json here")\n')
    assert len(store_literals([bad])) == 2  # the check can fail
    repo = ROOT.parent
    files = [p for d in ("proctex", "workers", "workflows") for p in (repo / d).rglob("*.py") if p.relative_to(repo).as_posix() != "proctex/store/layout.py" and "node_modules" not in p.parts]
    assert not store_literals(files), "store paths spelled outside proctex/store/layout.py's StoreLayout:\n" + "\n".join(store_literals(files))


def test_store_layout_names():
    from proctex.store.layout import StoreLayout, group_file_name

    assert StoreLayout.model(7) == "models/group_7.pt" and StoreLayout.model_group("group_7.pt") == 7
    for name in ("group_x.pt", "other.pt", "group_7.pth", "group_-1.pt", "group_.pt"):
        assert StoreLayout.model_group(name) is None
    assert StoreLayout.pair("s0001", 2) == "correspondences/s0001__g2.parquet" and StoreLayout.pair_record("s0001", 2).endswith(".json")
    assert group_file_name(3, "seat cushion/../x") == "group_3_seat_cushion____x.png" and group_file_name(0, "") == "group_0.png"
    assert StoreLayout.texture(3, "leg") == "template/group_3_leg.png"


def private_imports(root: Path, layers: dict[str, int]) -> list[str]:
    """``"module: name from other"`` for every name starting with ``_`` that a module of the package at
    ``root`` imports from a module of another unit of ``layers`` (``from x import _y``, or the module
    ``_y`` itself): a unit's privates are its own."""
    modules = {module_name(p, root): p for p in root.rglob("*.py")}
    bad = []
    for mod, path in sorted(modules.items()):
        if "_reference" in mod.split("."):  # the slow references test the privates they mirror
            continue
        package = package_of(mod, path)
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if not isinstance(node, ast.ImportFrom):
                continue
            target = import_target(node, package)
            if target.split(".")[0] != root.name:
                continue
            for a in node.names:
                full = f"{target}.{a.name}"
                owner = full if full in modules else target
                dunder = a.name.startswith("__") and a.name.endswith("__")  # __version__ and its kind are public
                if a.name.startswith("_") and not dunder and unit_of(owner, layers) != unit_of(mod, layers):
                    bad.append(f"{mod}: {a.name} from {target}")
    return bad


def test_no_unit_imports_another_units_privates(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "low").mkdir(parents=True)
    for f in ("__init__.py", "low/__init__.py"):
        (pkg / f).write_text("")
    (pkg / "low" / "a.py").write_text("def _helper():\n    pass\n")
    (pkg / "low" / "b.py").write_text("from .a import _helper\n")  # inside its own unit: fine
    (pkg / "high.py").write_text("from pkg.low.a import _helper\nfrom .low import a\n")
    assert private_imports(pkg, {"pkg.low": 0, "pkg.high": 1}) == ["pkg.high: _helper from pkg.low.a"]
    found = private_imports(ROOT, LAYERS)
    assert not found, "private names imported across units (make them public or keep them home):\n" + "\n".join(found)


def test_the_house_figures_count_deferred_imports_and_sizes_exactly():
    """tests/bench/house_figures.py (issue 55's aesthetics figures): a hand-made module with two own
    imports inside functions (one relative, one in a method), one outside and one of another package
    inside; a class and functions of known lengths; and the tree's own figures are well formed."""
    import sys

    sys.path.insert(0, str(ROOT.parent / "tests" / "bench"))
    from house_figures import definitions, figures, function_level_imports

    source = (
        "import proctex.params\n"  # module level: not counted
        "def f():\n"
        "    from . import x\n"  # relative: own
        "    import numpy\n"  # not own
        "    return x\n"
        "class C:\n"
        "    def m(self):\n"
        "        from proctex.store import layout\n"  # own, in a method
        "        return layout\n"
    )
    tree = ast.parse(source)
    assert function_level_imports(tree) == 2
    assert sorted(definitions(tree, "m")) == [("class", "m.C", 4), ("function", "m.C.m", 3), ("function", "m.f", 4)]
    f = figures(top=3)
    assert f["function_level_imports_in_proctex"] > 0 and len(f["largest_modules"]) == 3
    assert f["private_imports_across_units"] == []


def build_imports(root: Path) -> list[str]:
    """``"module -> target"`` for every import (functions included) of a build step under ``root``:
    ``proctex.build``, ``proctex.looks`` (painting a look), ``proctex.measure``."""
    steps = ("proctex.build", "proctex.looks", "proctex.measure")
    found = []
    for path in sorted(root.rglob("*.py")):
        mod = module_name(path, root)
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else [import_target(node, package_of(mod, path))] if isinstance(node, ast.ImportFrom) else []
            found += [f"{mod} -> {n}" for n in names if any(n == s or n.startswith(s + ".") for s in steps)]
    return found


def test_the_http_layer_runs_no_build_step_and_has_one_router_per_resource(tmp_path):
    """``workers/http`` reads requests and writes answers: it imports no build step (the service
    paints a look, :mod:`proctex.serve.lookviews`); each module of ``routes/`` makes one router
    whose paths no other router has, and the app serves exactly their union. The check finds a
    route module that imports the build."""
    import importlib

    from proctex.serve.catalog import Catalog
    from workers.http import create_app
    from workers.http.context import AppContext
    from workers.http.routes import studio

    http = ROOT.parent / "workers" / "http"
    assert build_imports(http) == []
    bad = tmp_path / "workers" / "http"
    bad.mkdir(parents=True)
    (bad / "r.py").write_text("def f():\n    from proctex.looks import changed_look\n")
    assert build_imports(bad) == ["http.r -> proctex.looks"]

    ctx = AppContext(lambda: Catalog(tmp_path), None, None, None, None, None)
    seen: dict[str, str] = {}
    for path in sorted((http / "routes").glob("*.py")):
        if path.stem == "__init__":
            continue
        module = importlib.import_module(f"workers.http.routes.{path.stem}")
        router = module.router(ctx, tmp_path) if module is studio else module.router(ctx)
        paths = {r.path for r in router.routes}
        assert paths, path.stem
        for p in paths:
            assert p not in seen, f"{p} in routes/{path.stem} and routes/{seen[p]}"
            seen[p] = path.stem
    app = create_app(lambda: Catalog(tmp_path), studio_dir=tmp_path)
    assert set(app.openapi()["paths"]) == {p for p, m in seen.items() if m != "studio"}
    assert len(set(seen.values())) == 8
