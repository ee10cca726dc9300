"""The fuzz suite (issue 18): a few hundred seeded hostile requests and command lines. Every answer
is a JSON status (never a plain-text 500, never an internal error) and every command ends with an
``error:`` line and exit 2 or succeeds; nothing hangs (each transfer has its budget)."""

from __future__ import annotations

import pytest

from proctex.serve.catalog import Catalog
from proctex.serve.service import Limits

from .fuzz_cases import cli_cases, http_cases

fastapi = pytest.importorskip("fastapi")
from fastapi.testclient import TestClient  # noqa: E402

from workers.http import create_app  # noqa: E402

ALLOWED = {200, 401, 403, 404, 405, 409, 413, 415, 422, 503}


@pytest.fixture(scope="module")
def root(painted_mug_root, tmp_path_factory):
    """A copy of the painted mug: the fuzzed edits may store some."""
    import shutil

    base = tmp_path_factory.mktemp("fuzz")
    shutil.copytree(painted_mug_root / "mug", base / "mug")
    return base


def run_http_cases(client, cases) -> dict[str, int]:
    """Run the cases; returns counts per outcome. Fails on a plain-text answer or a 500."""
    seen: dict[str, int] = {}
    for kind, method, path, kwargs in cases:
        r = getattr(client, method)(path, **kwargs)
        ctype = r.headers.get("content-type", "")
        assert r.status_code in ALLOWED, (kind, method, path[:120], r.status_code, r.text[:300])
        if r.status_code != 200:
            assert ctype.startswith("application/json") and isinstance(r.json().get("error"), str), (kind, path[:120], r.text[:300])
        seen[str(r.status_code)] = seen.get(str(r.status_code), 0) + 1
    return seen


def test_hostile_http_requests_get_json_answers(root):
    cat = Catalog(str(root), Limits(max_bytes=500_000, max_seconds=5.0), check_every=0)
    client = TestClient(create_app(lambda: cat, edit_token="fuzz-token-123"), headers={"X-ProcTex-Token": "fuzz-token-123"})
    cases = http_cases("mug", n=200, seed=0)
    seen = run_http_cases(client, cases)
    assert sum(seen.values()) == len(cases) and seen.get("422", 0) > 50
    assert client.get("/healthz").json()["status"] == "ok"  # and the service is still well


def test_hostile_command_lines_end_in_an_error_line(root, tmp_path, capsys):
    from proctex.cli import main

    for kind, argv in cli_cases(str(root / "mug"), str(tmp_path)):
        code = main(argv)
        err = capsys.readouterr().err
        assert code in (0, 2), (kind, argv[:4], code, err[-500:])
        if code == 2:
            assert err.startswith("error:") and "Traceback" not in err and "internal error" not in err, (kind, argv[:4], err[-500:])
    assert not [p for p in tmp_path.rglob("*") if p.name.endswith(".tmp")]
