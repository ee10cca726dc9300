"""The front's side channel into the transfer replicas (workers/sidechannel.py), without Ray: a
replica's listener in this process or in a child process that is killed under a request."""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from workers.sidechannel import ReplicaLost, SideChannel, Unreachable, listen, socket_name

NODE = "ab" * 28  # a node id's shape (56 hex digits)


async def _echo(request):
    return {"status": 200, "headers": [(b"x-n", str(len(request["body"])).encode())], "body": request["body"] * 2}


def test_a_request_and_its_answer_cross_whole_and_connections_are_reused(tmp_path):
    """Answers of 1 byte to 3 MB come back whole from a replica listening in this process; the
    second request on the same replica reuses the first one's connection; an error the replica's
    code raises is a ``RuntimeError`` naming it, and the connection still serves."""

    async def run():
        async def forward(request):
            if request.get("fail"):
                raise KeyError("boom")
            return await _echo(request)

        server = await listen(str(tmp_path), NODE, forward)
        side = SideChannel(str(tmp_path), NODE)
        try:
            for n in (1, 1000, 3 * 2**20):
                body = os.urandom(n)
                answer = await side.send({"body": body})
                assert answer["body"] == body * 2 and answer["headers"] == [(b"x-n", str(n).encode())]
            (path,) = side.idle
            assert len(side.idle[path]) == 1  # one connection served all three
            with pytest.raises(RuntimeError, match="KeyError: 'boom'"):
                await side.send({"body": b"x", "fail": True})
            assert (await side.send({"body": b"ok"}))["body"] == b"okok"
            assert side.sent == 5 and side.lost == 0
        finally:
            side.close()
            server.close()
            await server.wait_closed()

    asyncio.run(run())
    assert (tmp_path / socket_name(NODE, os.getpid())).exists()


def test_a_cancelled_request_cancels_the_replicas_run(tmp_path):
    """The front gives a request up (its client went away): its connection closes and the
    replica's run of it is cancelled (as a cancelled Serve handle call cancels it), and the next
    request is answered. A listener that ignored the close would leave the run going: the test can
    fail."""

    async def run():
        started, cancelled = asyncio.Event(), asyncio.Event()

        async def forward(request):
            if request["body"] == b"slow":
                started.set()
                try:
                    await asyncio.sleep(60)
                except asyncio.CancelledError:
                    cancelled.set()
                    raise
            return await _echo(request)

        server = await listen(str(tmp_path), NODE, forward)
        side = SideChannel(str(tmp_path), NODE)
        try:
            task = asyncio.ensure_future(side.send({"body": b"slow"}))
            await asyncio.wait_for(started.wait(), 10)
            task.cancel()
            with pytest.raises(asyncio.CancelledError):
                await task
            await asyncio.wait_for(cancelled.wait(), 10)
            assert (await side.send({"body": b"next"}))["body"] == b"nextnext"
        finally:
            side.close()
            server.close()
            await server.wait_closed()

    asyncio.run(run())


REPLICA = """
import asyncio, sys
from workers.sidechannel import listen

async def forward(request):
    if request["body"] == b"slow":
        await asyncio.sleep(60)
    return {"status": 200, "headers": [], "body": request["body"]}

async def main():
    await listen(sys.argv[1], sys.argv[2], forward)
    print("listening", flush=True)
    await asyncio.sleep(3600)

asyncio.run(main())
"""


def test_a_replica_killed_under_a_request_is_lost_and_its_stale_socket_is_passed_over(tmp_path):
    """A replica process SIGKILLed while it holds a request: the front's send raises
    :class:`ReplicaLost`, which :func:`workers.serve.lost` counts as lost (the ingress retries an
    idempotent request), and its socket is never tried again (a dying process's socket can still
    take a connection and reset it: the retry would be lost too). Its file stays behind; a front
    that did not see the loss finds nobody listening there, removes it and raises
    :class:`Unreachable` (nothing sent: the front takes the handle), as with no replica at all."""
    from workers.serve import lost

    root = Path(__file__).resolve().parents[1]
    proc = subprocess.Popen([sys.executable, "-c", REPLICA, str(tmp_path), NODE], stdout=subprocess.PIPE, cwd=root, env={**os.environ, "PYTHONPATH": str(root)})
    try:
        assert proc.stdout.readline().strip() == b"listening"
        sock = tmp_path / socket_name(NODE, proc.pid)

        async def run():
            side = SideChannel(str(tmp_path), NODE)
            assert (await side.send({"body": b"hi"}))["body"] == b"hi"
            task = asyncio.ensure_future(side.send({"body": b"slow"}))
            await asyncio.sleep(0.5)
            os.kill(proc.pid, signal.SIGKILL)
            with pytest.raises(ReplicaLost) as err:
                await asyncio.wait_for(task, 30)
            assert lost(err.value) and side.lost == 1 and side.departed == 1
            assert sock.exists()  # left behind by the killed process
            with pytest.raises(Unreachable):  # never tried again (a dying socket may still take one)
                await side.send({"body": b"again"})
            assert sock.exists() and side.lost == 1
            side.close()
            await asyncio.to_thread(proc.wait, 30)  # gone for good (while it exits, its socket may take one more)
            fresh = SideChannel(str(tmp_path), NODE)  # knows nothing of it: finds nobody listening
            with pytest.raises(Unreachable):
                await fresh.send({"body": b"again"})
            assert not sock.exists()  # stale: removed

        asyncio.run(run())
    finally:
        proc.kill()
        proc.wait()


def test_no_replica_is_unreachable_and_other_nodes_sockets_are_not_taken(tmp_path):
    """With no socket in the directory, or only another node's, the send raises
    :class:`Unreachable` at once (nothing sent)."""

    async def run():
        server = await listen(str(tmp_path), "cd" * 28, _echo)  # another node's replica
        try:
            side = SideChannel(str(tmp_path), NODE)
            t0 = time.monotonic()
            with pytest.raises(Unreachable):
                await side.send({"body": b"x"})
            assert time.monotonic() - t0 < 10  # a bound, not a timing: it does not wait
            assert (await SideChannel(str(tmp_path), "cd" * 28).send({"body": b"x"}))["body"] == b"xx"
        finally:
            server.close()
            await server.wait_closed()
        with pytest.raises(Unreachable):
            await SideChannel(str(tmp_path / "missing"), NODE).send({"body": b"x"})

    asyncio.run(run())


def test_the_side_channel_is_taken_only_where_serve_need_not_see_the_requests():
    """Fixed replicas holding every family take the side channel; multiplexed families (Serve
    routes by the family) and autoscaled replicas (Serve scales by the requests it sees) keep the
    handle."""
    from workers.front import takes_side_channel

    assert takes_side_channel({"root": "r", "replicas": "2"}, multiplexed=False)
    assert not takes_side_channel({"root": "r", "replicas": "2"}, multiplexed=True)
    assert not takes_side_channel({"root": "r", "min_replicas": "1"}, multiplexed=False)
    assert not takes_side_channel({"root": "r", "max_replicas": "4"}, multiplexed=False)


def test_the_side_channel_waits_for_every_replica_on_its_node(tmp_path):
    """With the deployment's count of replicas given, the side channel takes requests only while
    that many listen on this node (some elsewhere: the handle's router spreads the requests over
    all of them); once the second replica listens, requests go to both (fewest under way first).
    When the second is lost under a request, the first takes the rest: a replica of this node found
    dead still counts (the handle's router would not know yet, and could send the retry to it)."""

    async def run():
        first = await listen(str(tmp_path), NODE, _echo)
        side = SideChannel(str(tmp_path), NODE, replicas=2)
        try:
            with pytest.raises(Unreachable, match="1 of 2"):
                await side.send({"body": b"x"})
            # a second replica (listen() names its socket by this process's pid, taken already)
            second = await asyncio.start_unix_server(_answer, path=str(tmp_path / f"{NODE[:16]}.1.sock"))
            try:
                answers = await asyncio.gather(*(side.send({"body": b"y"}) for _ in range(4)))
                assert [a["body"] for a in answers] == [b"yy"] * 4
                assert len(side.idle) == 2  # both replicas served
                for _ in range(40):  # the second replica lost under a request (picked at random among the idle)
                    try:
                        await side.send({"body": b"die"})
                    except ReplicaLost:
                        break
                assert side.lost == 1 and side.departed == 1
                for _ in range(4):  # the first takes every request now: 1 of 2 listens, the other died here
                    assert (await side.send({"body": b"z"}))["body"] == b"zz"
            finally:
                second.close()
                await second.wait_closed()
        finally:
            side.close()
            first.close()
            await first.wait_closed()

    async def _answer(reader, writer):
        from workers.sidechannel import _read_message, _write_message

        while True:
            try:
                request = await _read_message(reader)
            except asyncio.IncompleteReadError:
                break
            if request["body"] == b"die":
                break  # the connection closes under the request, as a killed replica's does
            _write_message(writer, ("ok", await _echo(request)))
            await writer.drain()
        writer.close()

    asyncio.run(run())
