"""The suite passes on any CPU (issues 30 and 49).

Users' machines differ from CI's (AVX-512 or not, other OpenBLAS cores), where numpy's vectorised
transcendental functions, BLAS, torch's kernels and bfloat16 (emulated without AVX-512, so
``autocast="auto"`` takes float32) give other last bits. ``make test`` runs the fast ``numeric``
tests again under :func:`tests.portable.other_env` (kernels one tier below this CPU's); here: that
this environment really changes numpy's, BLAS's and torch's results, the slow close-to-the-bits
tests on it, and :func:`tests.portable.no_avx512_env` (an AVX-512 machine on an AVX2 one's paths).
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from .portable import glb_mismatch, native_env, no_avx512_env, numpy_avx512_targets

ROOT = Path(__file__).resolve().parents[1]

#: Slow tests whose checks sit close to float bits (two methods compared on identical shapes): the
#: fast ones run again on other kernels in every ``make test`` (the ``numeric`` marker), these here.
SLOW_MACHINE_SENSITIVE = [
    "tests/test_evaluate.py::test_methods_side_by_side_on_identical_shapes",
]

_PROBE = r"""
import json, sys
import numpy as np
try:
    from numpy._core._multiarray_umath import __cpu_features__ as feats, __cpu_dispatch__ as targets
except ImportError:
    from numpy.core._multiarray_umath import __cpu_features__ as feats, __cpu_dispatch__ as targets
import torch
from proctex.correspond.corrnet import native_bfloat16, resolve_autocast
x = np.linspace(-10.0, 10.0, 20001)
np.save(sys.argv[1], np.stack([np.exp(x / 3), np.log1p(np.abs(x)), np.arctan2(x, 1.3), np.power(np.abs(x), 0.7)]))
print(json.dumps(dict(avx512=[t for t in targets if feats.get(t) and (t.startswith("AVX512") or t == "X86_V4")],
                      aten=torch.backends.cpu.get_cpu_capability(), native_bf16=native_bfloat16(),
                      auto=resolve_autocast("auto"))))
"""


def _probe(env, out: Path) -> dict:
    import json

    run = subprocess.run([sys.executable, "-c", _PROBE, str(out)], env=env, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    return json.loads(run.stdout.strip().splitlines()[-1])


def test_the_no_avx512_environment_takes_the_other_paths(tmp_path):
    """Under :func:`no_avx512_env` numpy dispatches to no AVX-512 kernel, torch runs at AVX2, bfloat16 is
    not native ("auto" is float32); on an AVX-512 machine numpy's transcendental functions then give
    other last bits (the environment is not a no-op), within a few ULPs of this process's."""
    here = _probe(native_env(), tmp_path / "here.npy")
    there = _probe(no_avx512_env(), tmp_path / "there.npy")
    assert there["avx512"] == [] and there["native_bf16"] is False and there["auto"] == "none"
    if here["aten"].startswith("AVX"):  # x86 with AVX2 or more
        assert there["aten"] == "AVX2"
    a, b = np.load(tmp_path / "here.npy"), np.load(tmp_path / "there.npy")
    np.testing.assert_allclose(a, b, rtol=4 * np.finfo(np.float64).eps, atol=0)
    if numpy_avx512_targets() and here["avx512"]:
        assert not np.array_equal(a, b), "numpy took the same kernels with AVX-512 disabled"
    else:  # no AVX-512 here: both runs take the same kernels
        np.testing.assert_array_equal(a, b)


_KERNELS = r"""
import json, sys
import numpy as np
import torch
from proctex.torch_kernels import resolve_vml
resolve_vml()  # as the project's modules do: else MKL may pick a low-accuracy exp for one thread (issue 188792)
x = np.linspace(-10.0, 10.0, 20001)
rng = np.random.default_rng(0)
a, b = rng.standard_normal((256, 256)), rng.standard_normal((256, 64))
torch.manual_seed(0)
t, u = torch.randn(256, 256), torch.randn(256, 64)
np.savez(sys.argv[1], numpy=np.stack([np.exp(x.astype(np.float32) / 3).astype(np.float64), np.sin(x.astype(np.float32)).astype(np.float64),
                                      np.tanh(x / 3), np.exp(x / 3), np.arctan2(x, 1.3)]),
         blas=np.concatenate([(a @ b).ravel(), (a.astype(np.float32) @ b.astype(np.float32)).astype(np.float64).ravel(),
                              np.linalg.solve(a, b).ravel(), [a[0] @ a[1]]]),
         torch=np.concatenate([(t @ u).numpy().ravel(), torch.exp(t / 3).numpy().ravel(), torch.tanh(t).numpy().ravel()]))
print(json.dumps(dict(aten=torch.backends.cpu.get_cpu_capability())))
"""


def test_the_other_environment_takes_other_numpy_blas_and_torch_kernels(tmp_path):
    """:func:`tests.portable.other_env` (what ``make test`` runs the fast tests under a second time)
    differs from this machine's own kernels on any x86 CPU: numpy's vectorised functions, OpenBLAS
    and torch's ATen kernels each give other last bits (and agree to a few ULPs: the same functions).
    Which of them differ depends on the CPU: on an AVX2 machine (numpy without ``X86_V3``, BLAS at
    Sandybridge) float32 ``exp``/``sin``, float64 ``tanh`` and every product; on an AVX-512 one
    (Sapphire Rapids, seen on a lent machine) float64 ``exp``/``arctan2``, the float32 product, the
    solve and the dot product, while the float64 product of these sizes came out equal."""
    from .portable import cpu_tier, other_env

    def probe(env, name):
        run = subprocess.run([sys.executable, "-c", _KERNELS, str(tmp_path / name)], env=env, cwd=ROOT, capture_output=True, text=True, timeout=300)
        assert run.returncode == 0, run.stderr[-3000:]
        import json

        return json.loads(run.stdout.strip().splitlines()[-1]), np.load(tmp_path / f"{name}.npz")

    (here_info, here), (there_info, there) = probe(native_env(), "here"), probe(other_env(), "there")
    tier = cpu_tier()
    differ = {k: not np.array_equal(here[k], there[k]) for k in ("numpy", "blas", "torch")}
    # a few ULPs of each result's precision: float32 for numpy's first rows, float32 sums of 256
    # products of order 1 (about 1e-5 apart in their last bits) in BLAS's and torch's
    tol = {"numpy": (4 * 2.0**-23, 0.0), "blas": (1e-5, 1e-4), "torch": (1e-5, 1e-4)}
    for k in differ:
        np.testing.assert_allclose(here[k], there[k], rtol=tol[k][0], atol=tol[k][1])
    if tier in ("avx512", "avx2"):
        assert differ == {"numpy": True, "blas": True, "torch": True}, (tier, differ)
        assert there_info["aten"] == ("AVX2" if tier == "avx512" else "DEFAULT") != here_info["aten"]
    else:  # an older x86 or another architecture: at least BLAS's core type changes
        assert any(differ.values()), (tier, differ)


@pytest.mark.slow
def test_slow_machine_sensitive_tests_pass_on_other_kernels():
    from .portable import other_env

    run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *SLOW_MACHINE_SENSITIVE], env=other_env(), cwd=ROOT, capture_output=True, text=True, timeout=1200)
    assert run.returncode == 0, run.stdout[-6000:] + run.stderr[-2000:]
    passed = re.search(r"(\d+) passed", run.stdout)
    assert passed and int(passed.group(1)) >= len(SLOW_MACHINE_SENSITIVE), run.stdout[-2000:]  # every id ran


def test_glb_check_holds_under_noise_and_fails_on_changes():
    """:func:`tests.portable.glb_mismatch` (how generated GLBs of two runs are compared) passes what
    another thread count or CPU does (last-bit noise, a texel one level off) and fails what a code
    change does (a vertex moved, a texel three levels off, faces swapped, another material)."""
    from proctex.texture.export import glb_bytes

    from .meshes import cube

    v, f = cube()
    rng = np.random.default_rng(0)
    uv = rng.uniform(0, 1, (len(f), 3, 2))
    group = np.arange(len(f)) % 2
    tex = [rng.integers(0, 256, (16, 16, 3), dtype=np.uint8) for _ in range(2)]

    def glb(vertices=v, faces=f, textures=tex, names=("a", "b")):
        return glb_bytes(vertices, faces, uv, group, textures, list(names))

    base = glb()
    assert glb_mismatch(base, glb()) is None
    assert glb_mismatch(base, glb(vertices=v * (1 + 1e-12))) is None
    one_off = [t.copy() for t in tex]
    one_off[1][3, 4, 0] = one_off[1][3, 4, 0] + (1 if one_off[1][3, 4, 0] < 255 else -1)
    assert glb_mismatch(base, glb(textures=one_off)) is None
    moved = v.copy()
    moved[2, 1] += 1e-4
    assert "vertices" in glb_mismatch(base, glb(vertices=moved))
    three_off = [t.copy() for t in tex]
    three_off[0][0, 0, 2] = (int(three_off[0][0, 0, 2]) + 3) % 256
    assert "image" in glb_mismatch(base, glb(textures=three_off))
    assert "faces" in glb_mismatch(base, glb(faces=f[:, [1, 2, 0]]))
    assert "materials" in glb_mismatch(base, glb(names=("a", "c")))


def test_the_numeric_marker_is_found_in_each_tests_source(tmp_path):
    """A test that asserts an ordering or calls a tolerance helper (itself or through a helper of
    its module) is ``numeric``; one that compares exactly is not, nor any test of a module kept off
    the marker; every module kept off exists."""
    from .conftest import NOT_NUMERIC, numeric_tests

    src = """
import numpy as np

def _close(a, b):
    np.testing.assert_allclose(a, b, atol=1e-9)

def test_threshold():
    assert abs(0.1 - 0.1) < 1e-9

def test_helper():
    _close([1.0], [1.0])

def test_exact():
    assert [1, 2] == [1, 2]

def test_approx():
    import pytest
    assert 0.1 == pytest.approx(0.1)
"""
    (tmp_path / "test_some.py").write_text(src)
    assert numeric_tests(tmp_path / "test_some.py") == {"test_threshold": True, "test_helper": True, "test_exact": False, "test_approx": True}
    (tmp_path / "test_service.py").write_text(src)  # a module kept off the marker
    assert not any(numeric_tests(tmp_path / "test_service.py").values())
    assert all((ROOT / "tests" / name).is_file() for name in NOT_NUMERIC)


def test_modules_that_import_torch_resolve_mkl_kernels_first():
    """Every module of ``proctex`` that imports torch at its top calls
    :func:`proctex.torch_kernels.resolve_vml` at its top too (a fresh process's first ``torch.exp``
    on two threads can otherwise be 1e-4 off in one thread's chunk: CI saw it in this file's kernel
    probe); the check finds a module that forgets."""
    import ast

    def forgets(source: str) -> bool:
        tree = ast.parse(source)
        imports = any(isinstance(n, ast.Import) and any(a.name == "torch" for a in n.names) for n in tree.body)
        calls = any(isinstance(n, ast.Expr) and isinstance(n.value, ast.Call) and getattr(n.value.func, "id", None) == "resolve_vml" for n in tree.body)
        return imports and not calls

    assert forgets("import torch\nx = torch.exp(torch.ones(3))\n")
    assert not forgets("import torch\nfrom proctex.torch_kernels import resolve_vml\nresolve_vml()\n")
    assert not forgets("def f():\n    import torch\n")
    found = [str(p.relative_to(ROOT)) for p in sorted((ROOT / "proctex").rglob("*.py")) if forgets(p.read_text())]
    assert found == [], found
    assert len([p for p in (ROOT / "proctex").rglob("*.py") if "\nimport torch\n" in p.read_text()]) >= 8  # the check saw them


_RESOLVE = r"""
import json
import torch
from torch.overrides import TorchFunctionMode
import proctex.torch_kernels as k

calls = []
class Record(TorchFunctionMode):
    def __torch_function__(self, func, types, args=(), kwargs=None):
        if func.__name__ in k.VML_FUNCTIONS:
            calls.append((func.__name__, str(args[0].dtype), tuple(args[0].shape)))
        return func(*args, **(kwargs or {}))

with Record():
    first, second = k.resolve_vml(), k.resolve_vml()
import proctex.correspond.mvc  # noqa: F401  (resolves again: nothing to do)
print(json.dumps(dict(first=first, second=second, calls=calls, after=k.resolve_vml())))
"""


def test_resolve_vml_calls_each_mkl_function_once_per_precision_on_one_element():
    """In a fresh process :func:`resolve_vml` calls each of :data:`VML_FUNCTIONS` exactly once on a
    one-element float32 and float64 tensor (one thread's work), and only the first time."""
    import json

    from proctex.torch_kernels import VML_FUNCTIONS

    run = subprocess.run([sys.executable, "-c", _RESOLVE], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    got = json.loads(run.stdout.strip().splitlines()[-1])
    assert got["first"] is True and got["second"] is False and got["after"] is False
    want = sorted((f, d, [1]) for f in VML_FUNCTIONS for d in ("torch.float32", "torch.float64"))
    assert sorted(tuple(c) for c in got["calls"]) == [tuple(w) for w in want]
    assert len(VML_FUNCTIONS) == 16 and "exp" in VML_FUNCTIONS and "sqrt" in VML_FUNCTIONS
