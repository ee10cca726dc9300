"""The hostile probe of issue 18, rerunnable: the seeded HTTP and command-line cases of
``tests/fuzz_cases.py`` against a small built family, tallied by outcome.

    .venv/bin/python tests/bench/probe_service.py [--n 300] [--seed 0] [--out out/bench/probe.json]

HTTP outcomes: the status codes, plain-text answers, 500s and the slowest request. Command lines:
exit codes, tracebacks (an exception escaping ``main``) and ``internal error`` lines. Run it on an
older checkout (``PYTHONPATH=<checkout>``) to compare; it adapts to the older module layout.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # for fuzz_cases; proctex and workers come from PYTHONPATH / the install

from fuzz_cases import cli_cases, http_cases  # noqa: E402


def build_family(root: Path) -> None:
    try:
        from proctex.build.pipeline import stage_paint
        from proctex.build.pipeline import stage_sample
        from proctex.build.pipeline import stage_template
        from proctex.store.config import BuildConfig
        from proctex.store.layout import FamilyStore
        from proctex.store.state import write_config
    except ImportError:  # the layout before issue 33
        from proctex.family.config import BuildConfig
        from proctex.family.stages import (
            stage_paint,
            stage_sample,
            stage_template,
            write_config,
        )
        from proctex.family.store import FamilyStore
    cfg = BuildConfig.from_dict(dict(model="mug", n_train=2, n_test=0, texture_size=32, prompt="blue ceramic"))
    st = FamilyStore(root / "mug")
    write_config(st, cfg)
    for stage in (stage_sample, stage_template, stage_paint):
        stage(st, cfg, log=lambda *_: None)


def probe_http(root: Path, n: int, seed: int) -> dict:
    from fastapi.testclient import TestClient

    try:
        from proctex.serve.catalog import Catalog
        from proctex.serve.service import Limits
    except ImportError:  # older layouts, for before/after runs
        try:
            from proctex.serve.service import Catalog, Limits
        except ImportError:
            from proctex.service import Catalog, Limits
    from workers.http import create_app

    cat = Catalog(str(root), Limits(max_bytes=500_000), check_every=0)
    try:
        app = create_app(lambda: cat, edit_token="probe-token-123")
    except TypeError:  # no edit tokens before issue 18
        app = create_app(lambda: cat)
    client = TestClient(app, raise_server_exceptions=False, headers={"X-ProcTex-Token": "probe-token-123"})
    statuses: dict[str, int] = {}
    plain, slowest = 0, 0.0
    examples: list[str] = []
    cases = http_cases("mug", n=n, seed=seed)
    for kind, method, path, kwargs in cases:
        t = time.perf_counter()
        r = getattr(client, method)(path, **kwargs)
        slowest = max(slowest, time.perf_counter() - t)
        statuses[str(r.status_code)] = statuses.get(str(r.status_code), 0) + 1
        is_json = r.headers.get("content-type", "").startswith("application/json")
        if r.status_code != 200 and not is_json:
            plain += 1
            if len(examples) < 5:
                examples.append(f"{kind} {method.upper()} {path[:60]}: {r.status_code} {r.text[:80]!r}")
    return {
        "cases": len(cases),
        "statuses": dict(sorted(statuses.items())),
        "plain_text_errors": plain,
        "server_errors": statuses.get("500", 0),
        "slowest_seconds": round(slowest, 2),
        "examples": examples,
    }


def probe_cli(root: Path, out: Path) -> dict:
    from proctex.cli import main

    codes: dict[str, int] = {}
    tracebacks, internal = 0, 0
    cases = cli_cases(str(root / "mug"), str(out))
    for _, argv in cases:
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            try:
                code = main(argv)
            except SystemExit as exc:  # argparse
                code = exc.code if isinstance(exc.code, int) else 2
            except BaseException:  # an exception escaping main: a traceback for the user
                code, tracebacks = -1, tracebacks + 1
        internal += "internal error" in err.getvalue()
        codes[str(code)] = codes.get(str(code), 0) + 1
    stray = [str(p) for p in out.rglob("*") if p.name.endswith(".tmp")]
    return {"cases": len(cases), "exit_codes": dict(sorted(codes.items())), "tracebacks": tracebacks, "internal_errors": internal, "stray_tmp_files": len(stray)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=300, help="random HTTP cases on top of the fixed ones")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="out/bench/probe.json")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "families"
        build_family(root)
        (Path(tmp) / "cli").mkdir()
        report = {"http": probe_http(root, args.n, args.seed), "cli": probe_cli(root, Path(tmp) / "cli")}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(report, indent=1))
    print(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
