"""No client can hold the service by sending slowly (issue 34): a body that stalls, trickles or
never ends is answered 408 within the time bounds of :class:`proctex.serve.service.Limits`, and
bodies beyond ``max_uploads`` are refused at once (503, Retry-After) while the health route and
other requests are answered; small (JSON) bodies have slots of their own."""

from __future__ import annotations

import asyncio
import contextlib
import shutil
import time

import numpy as np
import pytest

httpx = pytest.importorskip("httpx")

from proctex.serve.catalog import Catalog  # noqa: E402
from proctex.serve.service import Limits  # noqa: E402
from workers.http import create_app  # noqa: E402

LIMITS = dict(body_seconds=3.0, body_idle_seconds=0.4, body_min_rate=200, max_uploads=1)


#: Stalled bodies held until the test lets them go, however loaded the machine: what "answered
#: while they are held" needs (under LIMITS, a transfer slower than 0.4 s outlived them).
PATIENT = dict(LIMITS, body_seconds=120.0, body_idle_seconds=60.0)


def _client(app, address: str) -> httpx.AsyncClient:
    """A client of ``app`` in process whose requests come from ``address`` (the ASGI scope's peer:
    no packet leaves the process)."""
    return httpx.AsyncClient(transport=httpx.ASGITransport(app=app, client=(address, 40000)), base_url="http://t", timeout=120)


def _app(root, tmp_path, limits):
    shutil.copytree(root / "mug", tmp_path / "root" / "mug")
    cat = Catalog(str(tmp_path / "root"), Limits(**limits), check_every=0)
    cat.get("mug")
    return create_app(lambda: cat)


@pytest.fixture()
def app(painted_mug_root, tmp_path):
    return _app(painted_mug_root, tmp_path, LIMITS)


@pytest.fixture()
def patient_app(painted_mug_root, tmp_path):
    return _app(painted_mug_root, tmp_path, PATIENT)


async def _post(client, body, length=None):
    headers = {"content-type": "application/json"}
    if length is not None:
        headers["content-length"] = str(length)
    t = time.monotonic()
    r = await client.post("/v1/families/mug/transfer", content=body, headers=headers)
    return r, time.monotonic() - t


async def stalled(first: bytes = b'{"params": ', pause: float = 30.0, release: asyncio.Event | None = None, rest: bytes = b"{}}"):
    """A body that sends ``first``, then nothing for ``pause`` seconds or until ``release`` is set,
    then ``rest``."""
    yield first
    if release is not None:
        await release.wait()
    else:
        await asyncio.sleep(pause)
    yield rest


async def trickle(n: int = 100, every: float = 0.05):
    for _ in range(n):
        yield b" "
        await asyncio.sleep(every)


def test_stalled_trickling_and_endless_bodies_are_cut_off(app):
    async def run():
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="http://t", timeout=20) as c:
            r, took = await _post(c, stalled(), length=1000)  # lies about its length, then idles
            assert r.status_code == 408 and "nothing for 0.4 s" in r.json()["error"] and took < 5, (r.text, took)
            r, took = await _post(c, trickle())  # chunked, 20 bytes/s: under the minimum rate
            assert r.status_code == 408 and "bytes/s" in r.json()["error"] and took < 5, (r.text, took)
            r, took = await _post(c, b'{"params": {}}')  # a sound body still gets through
            assert r.status_code == 200 and r.content[:4] == b"glTF"

    asyncio.run(run())


def test_uploads_beyond_the_slots_are_refused_at_once_and_health_and_small_bodies_answer(patient_app):
    """While the one upload slot is held by a stalled body (held until the test lets it go: a minute
    of idle allowed), another upload is refused after the short wait for a slot (not after the
    held body ends), and the health route and a small body are answered."""
    big = 100_000  # over Limits.small_body: an upload

    async def run():
        async with _client(patient_app, "192.0.2.1") as a, _client(patient_app, "192.0.2.2") as c:
            release = asyncio.Event()
            holder = asyncio.create_task(_post(a, stalled(release=release, rest=b"}}"), length=big))  # another client holds the slot
            await asyncio.sleep(0.05)
            r, took = await _post(c, b" " * big)
            # the wait for a slot is min(1 s, half the idle bound): refused after it, long before the held body ends
            assert r.status_code == 503 and r.headers.get("retry-after") == "1" and "uploads" in r.json()["error"] and took < 30
            h = await c.get("/healthz")
            assert h.status_code == 200
            r, _ = await _post(c, b'{"params": {}}')  # a small body has slots of its own
            assert r.status_code == 200 and not holder.done()
            release.set()
            held, _ = await holder  # let go, it ends: read, then refused as bad JSON
            assert held.status_code == 422
            r, _ = await _post(c, b" " * big)  # the upload slot is free again: read, then refused as bad JSON
            assert r.status_code == 422
            r, _ = await _post(c, b" " * big)  # the upload slot is free again: read, then refused as bad JSON
            assert r.status_code == 422

    asyncio.run(run())


def test_forty_stalled_small_bodies_hold_neither_health_nor_transfers(patient_app):
    """The issue's attack: 40 bodies declaring 1,000 bytes, stalled after 10. Each holds one of
    ``max_small_bodies`` slots (held until the test lets them go); the health route and a transfer
    are answered while all 40 are still held. (That a stalled body is cut off in time is the first
    test's.)"""

    async def run():
        async with contextlib.AsyncExitStack() as stack:  # forty clients (one's share is client_small_bodies)
            senders = [await stack.enter_async_context(_client(patient_app, f"198.51.100.{k + 1}")) for k in range(40)]
            c = await stack.enter_async_context(_client(patient_app, "192.0.2.2"))
            release = asyncio.Event()
            holders = [asyncio.create_task(_post(s, stalled(release=release, rest=b"}}"), length=1000)) for s in senders]
            await asyncio.sleep(0.05)
            h = await c.get("/healthz")
            r, _ = await _post(c, b'{"params": {}}')
            assert h.status_code == 200 and r.status_code == 200 and r.content[:4] == b"glTF"
            assert not any(t.done() for t in holders)  # answered while every stalled body is still held
            release.set()
            held = [r for r, _ in await asyncio.gather(*holders)]
            assert {r.status_code for r in held} == {422}  # let go, each ends: read, then refused as bad JSON

    asyncio.run(run())


def test_body_limits_are_checked():
    for bad in (dict(body_seconds=0), dict(body_idle_seconds=float("nan")), dict(max_uploads=0), dict(body_min_rate=True), dict(max_small_bodies=0), dict(small_body=-1)):
        with pytest.raises(ValueError, match="limit"):
            Limits(**bad)


def test_the_limits_are_settable_for_serve_and_checked_before_ray_starts(painted_mug_root, capsys):
    from workers.serve import limits_from
    from workflows.cli import main

    assert limits_from({"root": "x", "body_seconds": "5", "max_uploads": "2"}) == {"body_seconds": 5.0, "max_uploads": 2}
    with pytest.raises(ValueError, match="max_uploads"):
        limits_from({"max_uploads": "0"})
    for flag, message in (("bogus=1", "NAME=VALUE"), ("body_min_rate=slow", "must be a number"), ("body_idle_seconds=-1", "positive")):
        assert main(["serve", str(painted_mug_root), "--limit", flag]) == 2
        assert message in capsys.readouterr().err, flag


def test_uploads_are_read_in_a_process_that_is_killed_past_the_budget(painted_mug_root, sofa_dir):
    """The mesh reader process reads exactly what the library reads; past its deadline, or when
    its request is cancelled, it is killed (a thread cannot be) and the next read starts a new one."""
    from proctex.geometry.meshio import load_mesh_bytes
    from proctex.serve.parse_worker import MeshReader, ReadTimeout
    from proctex.serve.service import FamilyService
    from proctex.store.layout import FamilyStore
    from proctex.transfer.budget import Budget, OverBudget

    reader = MeshReader()
    try:
        data = (sofa_dir / "train" / "0.obj").read_bytes()
        with pytest.raises(ReadTimeout, match="ran past"):
            reader.read(data, "sofa.obj", seconds=0.01)  # a cold reader cannot even start in 10 ms
        assert reader.kills == 1
        with pytest.raises(ReadTimeout, match="cancelled"):
            reader.read(data, "sofa.obj", seconds=30, cancelled=lambda: True)  # cancelled before it started: nothing to kill
        assert reader.kills == 1
        answers = iter([False] + [True] * 100)  # cancelled while the reader reads
        with pytest.raises(ReadTimeout, match="cancelled"):
            reader.read(data, "sofa.obj", seconds=30, cancelled=lambda: next(answers))
        assert reader.kills == 2
        shape = reader.read(data, "sofa.obj", groups=True, seconds=60)
        here, _ = load_mesh_bytes(data, "sofa.obj", groups=True)
        assert np.array_equal(shape.vertices, here.vertices) and np.array_equal(shape.faces, here.faces)
        with pytest.raises(ValueError, match="no vertices|no faces|empty"):
            reader.read(b"# nothing\n", "x.obj", seconds=60)
    finally:
        reader.close()
    svc = FamilyService(FamilyStore(painted_mug_root / "mug"))
    budget = Budget(30.0)
    budget.cancel()
    with pytest.raises(OverBudget) as err:
        svc.shape_from_mesh(data, "sofa.obj", budget=budget)
    assert err.value.cancelled


def test_a_reader_that_never_takes_the_upload_cannot_hold_the_request_past_its_deadline():
    """The upload's way into the reader counts against the deadline: a reader process stuck before
    reading its input (here one that only sleeps) leaves a 1 MB upload in a full pipe, and the
    read still ends in :class:`ReadTimeout` at its deadline, the stuck process killed. Before, the
    send blocked until the reader took it, outside the deadline (a stuck reader held the request
    for good)."""
    import subprocess
    import sys
    import time

    from proctex.serve.parse_worker import MeshReader, ReadTimeout

    reader = MeshReader()
    stuck = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"], stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    reader._proc = stuck  # the reader the next read finds running
    t0 = time.monotonic()
    try:
        with pytest.raises(ReadTimeout, match="ran past 0.5 s"):
            reader.read(b"v 0 0 0\n" * 131_072, "big.obj", seconds=0.5)
        assert time.monotonic() - t0 < 20  # not the sleeper's 60 s (a bound, not a timing: 0.5 s expected)
        assert stuck.poll() is not None and reader.kills == 1
    finally:
        stuck.kill()
        stuck.wait()
        reader.close()


def test_one_client_holds_its_share_of_the_slots_and_every_other_client_is_served(patient_app):
    """The attack of issue 54: one client opens 260 connections that each send a header declaring
    1,000 bytes and 9 of them. It holds client_small_bodies (64 of the 256) slots; its other bodies wait a
    moment and are refused (429, Retry-After), while another client's transfers and edits answer
    (before, the one client took all 256 small-body slots and every other client got 503)."""

    async def run():
        async with _client(patient_app, "192.0.2.1") as bad, _client(patient_app, "192.0.2.2") as good:
            release = asyncio.Event()
            holders = [asyncio.create_task(_post(bad, stalled(release=release, rest=b"}}"), length=1000)) for _ in range(260)]
            deadline = time.monotonic() + 60  # past the wait for a slot (1 s) the ones over the share are answered
            while sum(t.done() for t in holders) < 260 - 64 and time.monotonic() < deadline:
                await asyncio.sleep(0.1)
            await asyncio.sleep(0.3)  # and no more than those
            refused = [t.result()[0] for t in holders if t.done()]
            assert len(refused) == 260 - 64 and {r.status_code for r in refused} == {429}, len(refused)
            assert all(r.headers.get("retry-after") == "1" and "its share" in r.json()["error"] for r in refused)
            for _ in range(3):
                r, _ = await _post(good, b'{"params": {}}')
                assert r.status_code == 200 and r.content[:4] == b"glTF"
            r, _ = await _post(bad, b'{"params": {}}')  # the attacker's own sound request waits its share too
            assert r.status_code == 429
            release.set()
            held = await asyncio.wait_for(asyncio.gather(*[t for t in holders if not t.done()]), 60)
            assert len(held) == 64 and {r.status_code for r, _ in held} == {422}  # let go: read, then refused as bad JSON

    asyncio.run(run())


def test_the_client_is_its_peer_or_what_trusted_proxies_forward_and_ipv6_counts_by_64():
    from starlette.requests import Request

    from workers.http import client_of

    def req(peer, xff=None):
        headers = [(b"x-forwarded-for", xff.encode())] if xff else []
        return Request({"type": "http", "method": "GET", "path": "/", "headers": headers, "client": (peer, 1), "query_string": b""})

    proxies = Limits(trusted_proxies="10.1.0.0/16, 2001:db8:ffff::1").proxies()
    assert client_of(req("192.0.2.7")) == "192.0.2.7"
    assert client_of(req("192.0.2.7", "203.0.113.9")) == "192.0.2.7"  # not a trusted proxy: its header is the client's word
    assert client_of(req("10.1.2.3", "203.0.113.9"), proxies) == "203.0.113.9"
    assert client_of(req("10.1.2.3", "198.51.100.1, 203.0.113.9, 10.1.9.9"), proxies) == "203.0.113.9"  # the last hop not a proxy
    assert client_of(req("2001:db8:1:2:aaaa::1")) == client_of(req("2001:db8:1:2:bbbb::2")) == "2001:db8:1:2::/64"
    assert client_of(req("2001:db8:1:3::1")) != client_of(req("2001:db8:1:2::1"))
    assert client_of(req("::ffff:192.0.2.7")) == "192.0.2.7"
    with pytest.raises(ValueError, match="trusted_proxies"):
        Limits(trusted_proxies="not-an-address")
