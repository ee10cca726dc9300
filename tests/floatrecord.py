"""A pytest plugin that records every float check the tests make, with its value and its threshold
(issue 49): how close each check sits to its limit, so that runs under other CPU kernels and under
load show which margins are thinner than the noise (``python -m tests.float_margins``).

Recorded, for calls made from files under the session's ``tests/`` folder (else its root) only:

- every passing ``assert`` whose explanation compares two numbers (``a < b``, ``a >= b``, ``and``/``or``
  of comparisons; of a chain ``a < b < c`` pytest explains only the last link; two integers are
  skipped: counts are exact), through pytest's ``pytest_assertion_pass`` hook (it needs
  ``-o enable_assertion_pass_hook=true``; the modules rewritten with it are cached under names of
  their own);
- ``x == pytest.approx(y, ...)`` (value ``|x - y|``, threshold the approx's tolerance);
- ``numpy.testing.assert_allclose``, ``numpy.allclose`` and ``torch.testing.assert_close``: the
  value is the largest ``|a - b| / (atol + rtol * |b|)`` over the elements, the threshold 1.

A check that fails is not recorded (its test's outcome line says it failed). One line of JSON per
check in the file named by ``PROCTEX_FLOAT_RECORD``: ``test`` (node id), ``where`` (``file:line``),
``n`` (how many times that line ran before in the test), ``k`` (the comparison's place in the
assertion), ``kind``, ``value``, ``threshold``, ``op``; and one per test: ``test``, ``outcome``,
``numeric``, ``slow`` (its markers); each line also says the ``kernels`` it ran on (``native``, or
``other (...)`` under :func:`tests.portable.other_env`). Off unless that variable is set.
"""

from __future__ import annotations

import json
import math
import os
import re
import sys

import pytest

#: At most this many records per (test, line): a check inside a loop over thousands of items keeps
#: its first ones.
MAX_PER_SITE = 400

_BARE = r"-?(?:\d+\.\d*|\.\d+|\d+)(?:e[+-]?\d+)?|-?inf|nan"
# a number alone or in a scalar's repr (np.float64(0.5), tensor(0.5)); a number that ends a
# bracketed expression ("(a - 0.5) < 1") is not a side of the comparison
_NUM = r"(?:(?:np|numpy)\.(?:float|int|uint)\d+\((" + _BARE + r")\)|tensor\((" + _BARE + r")\)|(?<![\w.)])(" + _BARE + r")(?![\w.(]))"
_CMP = re.compile(_NUM + r"\s*(<=|>=|<|>)\s*(?=" + _NUM + r")")
_APPROX = re.compile(_NUM + r"\s*==\s*" + _NUM + r"\s*±\s*" + _NUM)


def _first(groups) -> str:
    return next(g for g in groups if g is not None)


def _is_int(token: str, text: str) -> bool:
    return re.fullmatch(r"-?\d+", token) is not None and "float" not in text


class Recorder:
    def __init__(self, path: str, base: str):
        self.base = base.rstrip(os.sep) + os.sep
        self.top = os.path.dirname(base.rstrip(os.sep))
        self.out = open(path, "a", encoding="utf-8")
        self.kernels = os.environ.get("PROCTEX_KERNELS", "native")  # set by tests.portable.other_env
        self.item = None
        self.counts: dict[tuple[str, str], int] = {}

    def where(self) -> str | None:
        """``file:line`` of the innermost frame under the recorded folder (not this file)."""
        f = sys._getframe(2)
        while f is not None:
            name = f.f_code.co_filename
            if name.startswith(self.base) and not name.endswith("floatrecord.py"):
                return f"{os.path.relpath(name, self.top)}:{f.f_lineno}"
            f = f.f_back
        return None

    def write(self, where: str, kind: str, pairs: list[tuple[float, float, str]]) -> None:
        if self.item is None or not pairs:
            return
        key = (self.item.nodeid, where)
        n = self.counts.get(key, 0)
        self.counts[key] = n + 1
        if n >= MAX_PER_SITE:
            return
        for k, (value, threshold, op) in enumerate(pairs):
            if not (math.isfinite(value) and math.isfinite(threshold)):
                continue
            self.out.write(json.dumps(dict(test=self.item.nodeid, where=where, n=n, k=k, kind=kind, value=value, threshold=threshold, op=op, kernels=self.kernels)) + "\n")
        self.out.flush()


_REC: Recorder | None = None

if os.environ.get("PROCTEX_FLOAT_RECORD"):
    # Test modules rewritten with the pass hook are cached under names of their own (pytest's
    # rewrite cache has one name per module otherwise: a run would load a stale rewrite without
    # the hook). Not PYTHONPYCACHEPREFIX: where bytecode is not written, every import of every
    # process would then compile from source.
    from _pytest.assertion import rewrite as _rewrite

    _rewrite.PYC_TAIL = ".floatrecord" + _rewrite.PYC_TAIL


def parse_explanation(expl: str) -> list[tuple[str, float, float, str]]:
    """The numeric comparisons in the first line of a passing assertion's explanation:
    ``[(kind, value, threshold, op)]``; approx comparisons as ``|x - y|`` against the tolerance."""
    line = expl.split("\n", 1)[0]
    found = []
    for m in _APPROX.finditer(line):
        g = m.groups()
        x, y, tol = float(_first(g[0:3])), float(_first(g[3:6])), float(_first(g[6:9]))
        found.append(("approx", abs(x - y), tol, "<="))
    line = _APPROX.sub("", line)
    pos = 0
    while True:
        m = _CMP.search(line, pos)
        if m is None:
            break
        rest = re.match(_NUM, line[m.end() :])
        left, op, right = _first(m.groups()[0:3]), m.group(4), _first(rest.groups())
        if not (_is_int(left, m.group(0)) and _is_int(right, rest.group(0))):
            found.append(("compare", float(left), float(right), op))
        pos = m.end()  # a chain a < b < c: b starts the next
    return found


def _ratio(actual, desired, rtol: float, atol: float) -> float | None:
    import numpy as np

    try:
        a = np.asarray(actual, dtype=np.float64)
        b = np.asarray(desired, dtype=np.float64)
        a, b = np.broadcast_arrays(a, b)
    except Exception:
        return None
    if a.size == 0:
        return None
    both = np.isfinite(a) & np.isfinite(b)
    if not both.any():
        return None
    d = np.abs(a[both] - b[both])
    tol = atol + rtol * np.abs(b[both])
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(tol > 0, d / np.where(tol > 0, tol, 1.0), np.where(d > 0, np.inf, 0.0))
    return float(r.max())


def _wrap_numpy():
    import numpy as np
    import numpy.testing

    original_assert, original_allclose = numpy.testing.assert_allclose, np.allclose

    def assert_allclose(actual, desired, rtol=1e-7, atol=0, *args, **kwargs):
        original_assert(actual, desired, rtol, atol, *args, **kwargs)
        if _REC is not None and (where := _REC.where()):
            r = _ratio(actual, desired, rtol, atol)
            if r is not None:
                _REC.write(where, "allclose", [(r, 1.0, "<=")])

    def allclose(a, b, rtol=1e-05, atol=1e-08, equal_nan=False):
        result = original_allclose(a, b, rtol, atol, equal_nan)
        if _REC is not None and (where := _REC.where()):
            r = _ratio(a, b, rtol, atol)
            if r is not None:
                _REC.write(where, "allclose", [(r, 1.0, "<=")])
        return result

    numpy.testing.assert_allclose = assert_allclose
    np.allclose = allclose


_TORCH_TOL = {"float64": (1e-7, 1e-7), "float32": (1.3e-6, 1e-5), "bfloat16": (1.6e-2, 1e-5), "float16": (1e-3, 1e-5)}


def _wrap_torch():
    try:
        import torch
        import torch.testing
    except ImportError:
        return
    original = torch.testing.assert_close

    def assert_close(actual, expected, *args, rtol=None, atol=None, **kwargs):
        original(actual, expected, *args, rtol=rtol, atol=atol, **kwargs)
        if _REC is None or not (where := _REC.where()):
            return
        try:
            dtype = str(getattr(actual, "dtype", "float64")).replace("torch.", "")
            r0, a0 = _TORCH_TOL.get(dtype, (0.0, 0.0))
            a = actual.detach().double().cpu().numpy() if hasattr(actual, "detach") else actual
            b = expected.detach().double().cpu().numpy() if hasattr(expected, "detach") else expected
            r = _ratio(a, b, r0 if rtol is None else rtol, a0 if atol is None else atol)
        except Exception:
            return
        if r is not None:
            _REC.write(where, "allclose", [(r, 1.0, "<=")])

    torch.testing.assert_close = assert_close


def pytest_configure(config):
    global _REC
    path = os.environ.get("PROCTEX_FLOAT_RECORD")
    if not path:
        return
    if not config.getini("enable_assertion_pass_hook"):
        raise pytest.UsageError("tests.floatrecord needs -o enable_assertion_pass_hook=true (python -m tests.float_margins sets it)")
    tests = config.rootpath / "tests"
    _REC = Recorder(path, str(tests if tests.is_dir() else config.rootpath))
    _wrap_numpy()
    _wrap_torch()


def pytest_unconfigure(config):
    global _REC
    if _REC is not None:
        _REC.out.close()
        _REC = None


@pytest.hookimpl(wrapper=True)
def pytest_runtest_call(item):
    if _REC is not None:
        _REC.item = item
    try:
        return (yield)
    finally:
        if _REC is not None:
            _REC.item = None


def pytest_runtest_logreport(report):
    """Each test's outcome (``{"test", "outcome"}``), so that a report tells a check a run did not
    make (its test failed, or did not run there) from one a passing test skipped."""
    if _REC is not None and (report.when == "call" or report.outcome != "passed"):
        _REC.out.write(
            json.dumps(dict(test=report.nodeid, outcome=report.outcome, when=report.when, kernels=_REC.kernels, numeric="numeric" in report.keywords, slow="slow" in report.keywords)) + "\n"
        )
        _REC.out.flush()


def pytest_assertion_pass(item, lineno, orig, expl):
    if _REC is None or _REC.item is None:
        return
    found = parse_explanation(expl)
    if not found:
        return
    path = os.path.relpath(str(item.path), _REC.top)
    # the assertion's own file and line (a helper's assert in another file: its file is not the item's)
    frame = sys._getframe(1)
    while frame is not None and frame.f_lineno != lineno:
        frame = frame.f_back
    if frame is not None and frame.f_code.co_filename.startswith(_REC.base):
        path = os.path.relpath(frame.f_code.co_filename, _REC.top)
    kinds = {kind for kind, *_ in found}
    _REC.write(f"{path}:{lineno}", "approx" if kinds == {"approx"} else "compare", [(v, t, op) for _, v, t, op in found])
