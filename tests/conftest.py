import ast
import re
import shutil
from pathlib import Path

import pytest

from tests.data import SOFA


@pytest.fixture(scope="session")
def sofa_dir() -> Path:
    if not SOFA.is_dir():
        pytest.skip(f"sofa data not found at {SOFA}")
    return SOFA


def require_validator() -> bool:
    """Whether GLBs can be run through the Khronos glTF validator here. Where npm exists the
    validator must be installed (``make setup`` does it): its absence fails the test instead of
    passing it unchecked. Without npm: False, and the test checks what it can without it."""
    from proctex.texture.export import validator_available

    if validator_available():
        return True
    if shutil.which("npm"):
        pytest.fail("the Khronos glTF validator is missing although npm is here: run `make setup`")
    return False


@pytest.fixture(scope="session")
def painted_mug_root(tmp_path_factory) -> Path:
    """A store root holding ``mug``: a painted mug family without networks (the identity mapper
    serves it), built once per test session. Tests that change it work on a copy."""
    from proctex.build.pipeline import stage_paint
    from proctex.build.pipeline import stage_sample
    from proctex.build.pipeline import stage_template
    from proctex.store.config import BuildConfig
    from proctex.store.layout import FamilyStore
    from proctex.store.state import write_config

    base = tmp_path_factory.mktemp("painted_mug")
    cfg = BuildConfig.from_dict(dict(model="mug", n_train=2, n_test=0, texture_size=32, prompt="blue ceramic"))
    st = FamilyStore(base / "mug")
    write_config(st, cfg)
    for stage in (stage_sample, stage_template, stage_paint):
        stage(st, cfg, log=lambda *_: None)
    return base


TOY_METHOD = '''"""A correspondence method in one file: the identity mirrored in x (a wrong map, on purpose)."""
import numpy as np

from proctex.transfer.methods import Method, register


class MirrorMapper:
    def map(self, group, vertices, faces, query, seed=0):
        return np.asarray(query, dtype=np.float64) * np.array([-1.0, 1.0, 1.0])


register(Method("toy_mirror", lambda ctx: MirrorMapper(), "the identity mirrored in x (a test's toy)"))
'''


@pytest.fixture()
def toy_method(tmp_path, monkeypatch):
    """The toy method's file named in PROCTEX_PLUGINS; unregistered afterwards."""
    from proctex import plugins
    from proctex.transfer.methods import unregister

    path = tmp_path / "toy_method.py"
    path.write_text(TOY_METHOD)
    monkeypatch.setenv("PROCTEX_PLUGINS", str(path))
    yield "toy_mirror"
    unregister("toy_mirror")
    plugins._LOADED.pop(str(path), None)


# ------------------------------------------------------------------------ the numeric marker
#: Modules whose float checks are about time, processes or files, not about what CPU kernels
#: compute (timings, leases, HTTP answers, pools, docs) or that choose kernels themselves
#: (test_portability): none of their tests is ``numeric``.
NOT_NUMERIC = frozenset(
    {
        "test_architecture.py",
        "test_bench.py",
        "test_cluster.py",
        "test_device.py",
        "test_docs.py",
        "test_float_margins.py",
        "test_fuzz.py",
        "test_hardening.py",
        "test_ingress.py",
        "test_jobs.py",
        "test_looks.py",
        "test_objectstore.py",
        "test_pools.py",
        "test_portability.py",
        "test_probe_faults.py",
        "test_ray.py",
        "test_service.py",
        "test_slow_clients.py",
        "test_studio.py",
        "test_workers.py",
        "test_writes.py",
    }
)
_FLOAT_CALLS = re.compile(r"allclose|approx\(|assert_close|isclose|assert_array_less|assert_sketch_close|sketch_mismatch|glb_mismatch")
_NUMERIC_CACHE: dict[str, dict[str, bool]] = {}


def _compares_floats(node: ast.AST, lines: list[str]) -> bool:
    """Whether a test function's body checks a float with a tolerance: a call of a tolerance helper,
    or an ``assert`` with an ordering comparison (``<``, ``<=``, ``>``, ``>=``). ``lines``: the
    module's source lines (the function's own are sliced by line number: ``ast.get_source_segment``
    splits the whole source again per call, a quarter of the suite's collection time)."""
    if _FLOAT_CALLS.search("".join(lines[node.lineno - 1 : node.end_lineno])):
        return True
    return any(isinstance(c, ast.Compare) and any(isinstance(o, (ast.Lt, ast.LtE, ast.Gt, ast.GtE)) for o in c.ops) for a in ast.walk(node) if isinstance(a, ast.Assert) for c in ast.walk(a.test))


def numeric_tests(path: Path) -> dict[str, bool]:
    """``{test function name: compares floats}`` for a test module (read once): in its own body, or
    in a function of the module it calls (a check helper)."""
    key = str(path)
    if key not in _NUMERIC_CACHE:
        source = path.read_text(encoding="utf-8")
        lines = source.splitlines(keepends=True)
        funcs = [n for n in ast.walk(ast.parse(source)) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))]
        helpers = {n.name for n in funcs if not n.name.startswith("test") and _compares_floats(n, lines)}
        found = {}
        for node in funcs:
            if node.name.startswith("test"):
                calls = {c.func.id for c in ast.walk(node) if isinstance(c, ast.Call) and isinstance(c.func, ast.Name)}
                found[node.name] = path.name not in NOT_NUMERIC and (_compares_floats(node, lines) or bool(calls & helpers))
        _NUMERIC_CACHE[key] = found
    return _NUMERIC_CACHE[key]


def pytest_collection_modifyitems(config, items):
    """Every test whose body compares floats with a tolerance carries ``numeric`` (found in its
    source, so a new test carries it as soon as it makes such a check): ``make test`` runs the fast
    ones again on other CPU kernels (tests/portable.py ``other_env``). ``python -m
    tests.float_margins report`` lists tests that made float checks without it (a check in a helper)."""
    for item in items:
        name = getattr(item, "originalname", None) or item.name.split("[")[0]
        if numeric_tests(Path(item.path)).get(name, False):
            item.add_marker(pytest.mark.numeric)
