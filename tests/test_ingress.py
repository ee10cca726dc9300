"""The ingress in front of the transfer replicas (issue 34): requests are forwarded whole and
answered as the app would answer them; a replica lost mid-request is answered in JSON, an
idempotent request retried once and an edit not; bodies are read within the time bounds at the
ingress. Replicas here are the real FastAPI app run by :func:`workers.ingress.call_app`, made to
fail on purpose; ``tests/test_ray.py`` kills a real Serve replica."""

from __future__ import annotations

import asyncio
import shutil

import pytest

httpx = pytest.importorskip("httpx")

from proctex.serve.catalog import Catalog  # noqa: E402
from proctex.serve.service import Limits  # noqa: E402
from workers.http import create_app  # noqa: E402
from workers.ingress import call_app, family_of, idempotent, ingress_app  # noqa: E402

TOKEN = "ingress-token"


class Lost(RuntimeError):
    """A replica that died under a request (the test's stand-in for Ray's ``ActorDiedError``)."""


@pytest.fixture()
def replica(painted_mug_root, tmp_path):
    shutil.copytree(painted_mug_root / "mug", tmp_path / "root" / "mug")
    cat = Catalog(str(tmp_path / "root"), Limits(body_idle_seconds=0.4, body_seconds=3.0, body_min_rate=200, max_uploads=1), check_every=0)
    cat.get("mug")
    return create_app(lambda: cat, edit_token=TOKEN, replica="r1")


def front(replica, fail: list, limits: Limits | None = None):
    """An ingress whose replica fails the next calls as ``fail`` says ("lost", "error" or None),
    and the list of (method, path, family) it forwarded."""
    calls = []

    async def forward(request, family):
        calls.append((request["method"], request["path"], family))
        what = fail.pop(0) if fail else None
        if what == "lost":
            raise Lost("the replica's actor died")
        if what == "error":
            raise KeyError("something else")
        if what == "lost-after":  # the replica did the work, then died before answering
            await call_app(replica, request)
            raise Lost("the replica's actor died")
        return await call_app(replica, request)

    limits = limits or Limits(body_idle_seconds=0.4, body_seconds=3.0, body_min_rate=200, max_uploads=1)
    return ingress_app(forward, limits, is_lost=lambda exc: isinstance(exc, Lost), retry_seconds=10), calls


def run(app, fn):
    async def go():
        async with httpx.AsyncClient(transport=httpx.ASGITransport(app=app), base_url="http://t", timeout=20) as c:
            return await fn(c)

    return asyncio.run(go())


def test_which_requests_are_retried_and_routed():
    assert idempotent("GET", "/v1/families/mug") and idempotent("POST", "/v1/families/mug/transfer")
    assert not idempotent("POST", "/v1/families/mug/edits") and not idempotent("DELETE", "/v1/families/mug/edits/last")
    assert not idempotent("POST", "/v1/families/mug/transfer/x")
    assert family_of("/v1/families/mug/transfer") == "mug" and family_of("/v1/families/mug") == "mug"
    assert family_of("/v1/families") is None and family_of("/healthz") is None


def test_every_route_answers_through_the_ingress_as_the_app_does(replica):
    app, calls = front(replica, [])

    async def go(c):
        direct = httpx.AsyncClient(transport=httpx.ASGITransport(app=replica), base_url="http://t", timeout=20)
        out = []
        for method, path, kw in (
            ("GET", "/healthz", {}),
            ("GET", "/v1/families", {}),
            ("GET", "/v1/families/nope", {}),
            ("POST", "/v1/families/mug/transfer", {"json": {"params": {}}}),
            ("POST", "/v1/families/mug/transfer", {"json": {"params": {"radius": 99}}}),
            ("GET", "/v1/families/mug/groups/0/texture.png?size=16", {}),
        ):
            a, b = await c.request(method, path, **kw), await direct.request(method, path, **kw)
            out.append((a.status_code, b.status_code, a.headers.get("content-type"), b.headers.get("content-type"), a.content == b.content))
        await direct.aclose()
        return out

    for via, plain, ctype_via, ctype_plain, same in run(app, go):
        assert via == plain and ctype_via == ctype_plain and same
    assert [family for _, _, family in calls] == [None, None, "nope", "mug", "mug", "mug"]


def test_a_lost_replica_is_retried_for_a_transfer_and_answered_in_json_otherwise(replica):
    async def go(c):
        ok = await c.post("/v1/families/mug/transfer", json={"params": {}})
        edit = await c.post("/v1/families/mug/edits", json={"group": 0, "hue": 30}, headers={"X-ProcTex-Token": TOKEN})
        twice = await c.post("/v1/families/mug/transfer", json={"params": {}})
        other = await c.get("/v1/families")
        return ok, edit, twice, other

    app, calls = front(replica, ["lost", None, "lost-after", "lost", "lost", "error"])
    ok, edit, twice, other = run(app, go)
    assert ok.status_code == 200 and ok.content[:4] == b"glTF" and ok.headers["x-proctex-retried"] == "1"
    assert edit.status_code == 503 and "not retried" in edit.json()["error"] and edit.headers["retry-after"] == "5"
    assert twice.status_code == 503 and "retry failed" in twice.json()["error"]
    assert other.status_code == 500 and other.json()["error"].startswith("internal error (KeyError)")
    assert [m for m, _, _ in calls] == ["POST", "POST", "POST", "POST", "POST", "GET"]  # the edit was sent once
    # the edit landed on the replica that was lost before answering: the family says so
    state = run(app, lambda c: c.get("/v1/families/mug"))
    assert state.status_code == 200 and state.json()["edits"] == 1, state.json().get("edits")


def test_without_the_retry_the_lost_transfer_would_fail(replica):
    """The check above can fail: a replica that is lost on every call gives no 200."""
    app, _ = front(replica, ["lost"] * 4)
    r = run(app, lambda c: c.post("/v1/families/mug/transfer", json={"params": {}}))
    assert r.status_code == 503 and r.headers["content-type"] == "application/json"


def test_bodies_are_read_within_the_time_bounds_at_the_ingress(replica):
    async def stalled():
        yield b'{"params": '
        await asyncio.sleep(5)
        yield b"{}}"

    async def go(c):
        holder = asyncio.create_task(c.post("/v1/families/mug/transfer", content=stalled(), headers={"content-type": "application/json", "content-length": "100000"}))
        await asyncio.sleep(0.1)
        busy = await c.post("/v1/families/mug/transfer", content=b" " * 100_000)  # the one upload slot is held
        health = await c.get("/healthz")  # no body: no slot needed
        return await holder, busy, health

    app, calls = front(replica, [])
    held, busy, health = run(app, go)
    assert held.status_code == 408 and "nothing for 0.4 s" in held.json()["error"]
    assert busy.status_code == 503 and busy.headers["retry-after"] == "1"
    assert health.status_code == 200 and health.json()["status"] == "ok"
    assert calls == [("GET", "/healthz", None)]  # neither body reached a replica
