"""The Ray layer on a 2-CPU local Ray: the distributed build equals the single-process one, survives
a killed worker and a killed driver (resuming without redoing work), and Ray Serve answers a bounded
concurrent load without errors."""

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from proctex.build.pipeline import build
from proctex.store.config import BuildConfig
from proctex.store.layout import FamilyStore
from proctex.store.samples import read_pair, samples

from .processes import pids_running

ray = pytest.importorskip("ray")
pytestmark = [pytest.mark.ray, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[1]
CFG = dict(
    model="mug",
    n_train=3,
    n_test=2,
    corr_points=200,
    cage_iterations=40,
    texture_size=32,
    prompt="blue ceramic",
    train={"iterations": 20, "eval_every": 10, "context_points": 128, "query_points": 64, "shapes_per_batch": 2},
)


def config() -> BuildConfig:
    return BuildConfig.from_dict(json.loads(json.dumps(CFG)))


@pytest.fixture(scope="module")
def local_ray():
    from workflows.build import init_ray

    init_ray(None, num_cpus=2)
    yield
    from ray import serve

    serve.shutdown()
    ray.shutdown()


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The single-process build of the same config (no evaluation)."""
    st = FamilyStore(tmp_path_factory.mktemp("ref") / "mug")
    build(st, config(), stages=("sample", "template", "paint", "pairs", "train"), log=lambda *_: None)
    return st


def _same_pairs(a: FamilyStore, b: FamilyStore) -> int:
    """The pairs of two stores agree: the same pairs solved (or skipped: a settled group's), the same data."""
    rows_a = {(r["id"], r["group"]): r for r in a.read_table("pairs.parquet").to_pylist()}
    rows_b = {(r["id"], r["group"]): r for r in b.read_table("pairs.parquet").to_pylist()}
    assert set(rows_a) == set(rows_b) and all(r["status"] in ("done", "skipped") for r in rows_b.values())
    assert {k: r["status"] for k, r in rows_a.items()} == {k: r["status"] for k, r in rows_b.items()}
    for sid, g in (k for k, r in rows_a.items() if r["status"] == "done"):
        (sa, da), (sb, db) = read_pair(a, sid, g), read_pair(b, sid, g)
        assert np.array_equal(sa, sb), (sid, g)
        assert np.allclose(da, db, atol=1e-5), (sid, g, np.abs(da - db).max())
    return len(rows_a)


def test_the_private_ray_runs_its_tasks_at_the_drivers_priority(local_ray):
    """Ray's default worker niceness (15) let any other process on a busy machine starve the
    build's tasks; the Ray the workflows start runs them at the driver's priority."""
    import os

    @ray.remote
    def niceness() -> int:
        return os.nice(0)

    assert ray.get(niceness.remote()) == os.nice(0)


def test_ray_build_equals_the_single_process_build(local_ray, reference, tmp_path):
    from proctex.correspond.corrnet import load
    from workflows.build import build_on_ray

    # The store as a URI (any pyarrow.fs URI works the same way; file:// needs no credentials).
    state = build_on_ray((tmp_path / "mug").as_uri(), config(), stages=("sample", "template", "paint", "pairs", "train"), train_workers=1, log=lambda *_: None, quiet=True)
    st = FamilyStore(tmp_path / "mug")
    assert {k for k, v in state["stages"].items() if v["state"] == "done"} == {"sample", "template", "paint", "pairs", "train"}
    assert set(state["wall_seconds"]) == {"sample", "template", "paint", "pairs", "train"}
    assert samples(st) == samples(reference)
    assert _same_pairs(reference, st) == 10
    for g in (0, 1):
        ma, _, _ = load(Path(reference.path(f"models/group_{g}.pt")))
        mb, _, _ = load(Path(st.path(f"models/group_{g}.pt")))
        sa, sb = ma.state_dict(), mb.state_dict()
        assert all(torch_allclose(sa[k], sb[k]) for k in sa), g
    # The serving choice is made and recorded the same way by Ray Train as in process.
    from proctex.store.networks import load_models

    mine, theirs = load_models(st), load_models(reference)
    record = st.read_json("family.json")["stages"]["train"]["groups"]
    for g in (0, 1):
        assert mine[g].serving["serve"] == theirs[g].serving["serve"] and record[str(g)]["serving"] == mine[g].serving
    # One train record whichever executor trained the group: the same fields, the team size included.
    ref_record = reference.read_json("family.json")["stages"]["train"]["groups"]
    for g in (0, 1):
        a, b = ref_record[str(g)], record[str(g)]
        assert set(b) == set(a) and a["workers"] == b["workers"] == 1
        assert b["iterations"] == a["iterations"] and set(b["best_val"]) == set(a["best_val"])
        assert all(b["best_val"][k] == pytest.approx(a["best_val"][k], rel=1e-3, abs=1e-6) for k in a["best_val"])
    assert st.listdir("train_runs"), "Ray Train checkpoints live in the store"


def torch_allclose(a, b) -> bool:
    import torch

    return bool(torch.allclose(a, b, atol=1e-4, rtol=1e-3))


def test_a_worker_killed_during_the_cage_fan_out_does_not_stop_the_build(local_ray, reference, tmp_path):
    from proctex.build.pipeline import run_stage
    from workflows.build import build_on_ray, ray_executor

    st_root = str(tmp_path / "mug")
    build_on_ray(st_root, config(), stages=("sample", "template", "paint"), log=lambda *_: None, quiet=True)
    killed: list[int] = []
    stop = threading.Event()

    def killer():
        while not stop.is_set() and not killed:
            pids = pids_running(b"ray::run_batch")
            if pids:
                time.sleep(0.3)  # let it get into a solve
                os.kill(pids[0], signal.SIGKILL)
                killed.append(pids[0])
            time.sleep(0.02)

    t = threading.Thread(target=killer)
    t.start()
    try:
        st, quiet = FamilyStore(st_root), (lambda *_: None)
        ran = []
        execute = ray_executor(quiet=True)
        run_stage(st, config(), "pairs", quiet, lambda *a: ran.append(execute(*a)) or ran[-1])  # both steps, recorded by the pipeline
    finally:
        stop.set()
        t.join()
    assert killed, "no pair task was seen running"
    st = FamilyStore(st_root)
    skipped = st.read_json("family.json")["stages"]["pairs"]["skipped"]
    assert sum(p.info["solved"] for p in ran) + skipped == 10
    st = FamilyStore(st_root)
    assert st.read_json("family.json")["stages"]["pairs"]["state"] == "done"
    assert _same_pairs(reference, st) == 10


def test_a_killed_driver_resumes_without_redoing_work(local_ray, reference, tmp_path):
    from workflows.build import build_on_ray

    cfg_file = tmp_path / "family.json"
    cfg_file.write_text(json.dumps(CFG))
    out = tmp_path / "mug"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    said = []  # what each build that ended before it could be killed said

    def start() -> subprocess.Popen:
        log = tmp_path / f"build{len(said)}.log"
        with open(log, "wb") as sink:
            proc = subprocess.Popen(
                [sys.executable, "-m", "workflows.cli", "build", str(cfg_file), "--out", str(out), "--ray", "--quiet", "--stages", "sample,template,paint,pairs"],
                cwd=ROOT,
                env=env,
                start_new_session=True,
                stdout=sink,
                stderr=subprocess.STDOUT,
            )
        deadline = time.time() + 240
        while time.time() < deadline and proc.poll() is None:
            if (out / "correspondences").exists() and len(list((out / "correspondences").glob("*.json"))) >= 3:
                break
            time.sleep(0.05)
        if proc.poll() is not None:
            said.append(f"exit {proc.poll()}: {log.read_text(errors='replace')[-1500:]}")
        return proc

    proc = start()
    if proc.poll() is not None and proc.poll() != 0 and not (out / "correspondences").exists():
        proc = start()  # it failed before its first pair (once seen on a loaded machine, exit 2): once more, and both logs if again
    st = FamilyStore(out)
    done_before: dict[str, int] = {}
    assert proc.poll() is None, "the build ended before it could be killed: " + " | ".join(said)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    recs = sorted((out / "correspondences").glob("*.json"))
    assert 3 <= len(recs) < 10
    for r in recs:
        done_before[r.name] = r.stat().st_mtime_ns
    # Rerun (same config): only the missing pairs are solved.
    build_on_ray(str(out), BuildConfig.from_file(cfg_file), stages=("sample", "template", "paint", "pairs"), log=lambda *_: None, quiet=True)
    for name, mtime in done_before.items():
        assert (out / "correspondences" / name).stat().st_mtime_ns == mtime, f"{name} was redone"
        assert json.loads((out / "correspondences" / name).read_text())["attempts"] == 1
    assert _same_pairs(reference, st) == 10
    assert not list(out.rglob("*.tmp-*")), "no partial files are left behind"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_serve_answers_every_route_and_a_concurrent_load(local_ray, reference, tmp_path):
    import shutil
    import urllib.error
    import urllib.request

    from ray import serve

    from workers.serve import build_app

    root = tmp_path / "families"
    shutil.copytree(reference.base, root / "mug")
    port = _free_port()
    serve.start(http_options={"host": "127.0.0.1", "port": port})
    serve.run(build_app({"root": str(root), "replicas": "1", "max_ongoing_requests": "8"}), name="proctex-test", route_prefix="/")
    base = f"http://127.0.0.1:{port}"

    def get(path):
        with urllib.request.urlopen(base + path, timeout=60) as r:
            return r.status, json.loads(r.read())

    def post(path, body: bytes, ctype="application/json"):
        req = urllib.request.Request(base + path, data=body, headers={"content-type": ctype}, method="POST")
        try:
            with urllib.request.urlopen(req, timeout=120) as r:
                return r.status, r.read()
        except urllib.error.HTTPError as e:
            return e.code, e.read()

    try:
        try:
            assert get("/healthz")[1]["status"] == "ok"
        except urllib.error.HTTPError as e:
            raise AssertionError(e.read()) from e
        with urllib.request.urlopen(base + "/", timeout=60) as r:  # the web studio's page
            assert r.status == 200 and b"<title>ProcTex studio</title>" in r.read()
        assert get("/v1/families")[1]["families"] == ["mug"]
        assert get("/v1/families/mug")[1]["groups"][1]["network"] is True
        code, body = post("/v1/families/mug/transfer", b'{"params": {"radius": 0.06}}')
        assert code == 422 and "radius" in json.loads(body)["error"]
        code, body = post("/v1/families/none/transfer", b'{"params": {}}')
        assert code == 404
        rng = np.random.default_rng(0)
        bodies = [json.dumps({"params": {"radius": float(rng.uniform(0.03, 0.05)), "height": float(rng.uniform(0.07, 0.13))}}).encode() for _ in range(200)]
        with ThreadPoolExecutor(8) as pool:
            results = list(pool.map(lambda b: post("/v1/families/mug/transfer", b), bodies))
        codes = [c for c, _ in results]
        assert codes.count(200) == 200, {c: codes.count(c) for c in set(codes)}
        assert all(b[:4] == b"glTF" for _, b in results)
    finally:
        serve.delete("proctex-test")


def test_the_demo_builds_on_ray_and_leaves_a_running_ray_as_it_was(local_ray, tmp_path):
    """``proctex demo`` (the main job) on the module's local Ray: the family is built by the Ray
    stages, every output is written, and the caller's Ray instance keeps running."""
    from workflows.demo import run_demo_on_ray

    tiny = {k: v for k, v in CFG.items() if k in ("corr_points", "cage_iterations", "texture_size", "train")}
    result = run_demo_on_ray(str(tmp_path / "demo"), model="mug", prompt="blue ceramic", n_train=3, n_test=2, rows=1, per_row=2, frames=3, log=lambda *_: None, quiet=True, overrides=tiny)
    s = result.summary
    assert s["ray"] is True and ray.is_initialized()
    state = json.loads((tmp_path / "demo" / "families" / "mug" / "family.json").read_text())
    assert state["stages"]["train"].get("ray") is True  # trained by Ray Train
    for path in (result.report, result.contact_sheet, result.turntable, *result.variants):
        assert Path(path).is_file() and Path(path).stat().st_size > 0


def test_a_group_trained_by_two_ray_train_workers_averages_their_gradients(local_ray, reference, tmp_path):
    """Ray Train's all-reduce path: one group, two workers in its team (the other tests train two
    groups on two workers: a team of one each, no all-reduce)."""
    import shutil

    from proctex.build.pipeline import run_stage
    from proctex.build.train import plan_train
    from proctex.store.networks import load_models
    from workflows.build import ray_executor

    shutil.copytree(reference.base, tmp_path / "mug")
    st = FamilyStore(str(tmp_path / "mug"))
    st.delete("models/group_0.pt")
    quiet = lambda *_: None  # noqa: E731
    cfg = BuildConfig.from_dict({**json.loads(json.dumps(CFG)), "train": {**CFG["train"], "plain_below": 0.0}})  # trained, whatever its box map
    plan = plan_train(st, cfg, quiet)
    assert plan.batches == [[0]]
    run_stage(st, cfg, "train", quiet, ray_executor(train_workers=2, quiet=True))  # placed as a team, recorded by the pipeline
    record = st.read_json("family.json")["stages"]["train"]
    assert record["ray"] is True and record["groups"]["0"]["workers"] == 2 and record["groups"]["0"]["sha256"]
    assert sorted(load_models(st)) == [0, 1]  # the new network's checksum is the one recorded


def _serve_app(root: Path, name: str, **args) -> str:
    from ray import serve

    from workers.serve import build_app

    serve.shutdown()  # a proxy started earlier keeps its port: start Serve afresh on a new one
    port = _free_port()
    serve.start(http_options={"host": "127.0.0.1", "port": port})
    serve.run(build_app({"root": str(root), **{k: str(v) for k, v in args.items()}}), name=name, route_prefix="/")
    return f"http://127.0.0.1:{port}"


def _transfer(base: str, family: str, routed: bool, radius: float = 0.04) -> tuple[int, str, bytes]:
    import urllib.error
    import urllib.request

    headers = {"content-type": "application/json", **({"serve_multiplexed_model_id": family} if routed else {})}
    req = urllib.request.Request(f"{base}/v1/families/{family}/transfer", data=json.dumps({"params": {"radius": radius}}).encode(), headers=headers, method="POST")
    try:
        with urllib.request.urlopen(req, timeout=120) as r:
            return r.status, r.headers.get("X-ProcTex-Replica", ""), r.read()
    except urllib.error.HTTPError as e:
        return e.code, "", e.read()


def test_a_multiplexed_replica_holds_at_most_its_cap_and_serves_every_family(local_ray, reference, tmp_path):
    """Three families, one replica with room for two: requests to all three succeed (the third
    pushes the least recently used one out), the replica holds two, and the evicted one loads
    again when asked for. Nothing is preloaded."""
    import shutil
    import urllib.request

    from ray import serve

    root = tmp_path / "families"
    for name in ("a", "b", "c"):
        shutil.copytree(reference.base, root / name)
    base = _serve_app(root, "proctex-mux", replicas=1, max_families=2)

    def health() -> dict:
        with urllib.request.urlopen(base + "/healthz", timeout=60) as r:
            return json.loads(r.read())

    try:
        first = health()
        assert first["loaded"] == [] and first["families"] == 3 and first["unavailable"] == []  # lazy: nothing loaded to answer
        for name in ("a", "b", "c"):
            code, _, body = _transfer(base, name, routed=True)
            assert code == 200 and body[:4] == b"glTF", body[:200]
        time.sleep(0.5)
        assert health()["loaded"] == ["b", "c"]
        code, _, _ = _transfer(base, "a", routed=True)
        state = health()
        assert code == 200 and state["loaded"] == ["a", "c"] and state["loads"] == 4
        with urllib.request.urlopen(base + "/v1/families", timeout=60) as r:
            assert json.loads(r.read())["health"] == {"a": "ok", "b": "ok", "c": "ok"}
    finally:
        serve.delete("proctex-mux")


def test_multiplexed_requests_go_to_the_replica_that_holds_their_family(local_ray, reference, tmp_path):
    """Two replicas with room for one family each, two families: every request of a family lands
    on one replica and each family loads once. The ingress routes by the family in the path, so
    requests without the ``serve_multiplexed_model_id`` header (curl's) are routed too."""
    import shutil
    import urllib.request

    from ray import serve

    root = tmp_path / "families"
    for name in ("a", "b"):
        shutil.copytree(reference.base, root / name)
    base = _serve_app(root, "proctex-route", replicas=2, max_families=1)
    try:
        seen: dict[str, set[str]] = {"a": set(), "b": set()}
        for k in range(16):
            family = "ab"[k % 2]
            code, replica, _ = _transfer(base, family, routed=False, radius=0.03 + 0.001 * k)
            assert code == 200
            seen[family].add(replica)
            time.sleep(0.2)  # replicas report what they hold every few tenths of a second
        assert all(len(r) == 1 for r in seen.values()) and seen["a"] != seen["b"], seen
        loads = []
        for _ in range(2):
            with urllib.request.urlopen(base + "/healthz", timeout=60) as r:
                loads.append(json.loads(r.read())["loads"])
        assert max(loads) <= 2, loads
    finally:
        serve.delete("proctex-route")


def test_serve_holds_against_stalled_clients_and_a_replica_killed_under_load(local_ray, reference, tmp_path):
    """Issue 34, on Serve (proxy, ingress, two transfer replicas). 40 clients open transfer bodies
    of 1,000 bytes and stall after 10: the health route and a transfer of another family are
    answered while all 40 are held. Then 50 transfers from 10 clients, one transfer replica
    SIGKILLed while it holds requests: Serve's proxy would answer those with a plain-text 500; the
    ingress retries each (a transfer is idempotent) on the other replica: every answer is a GLB or
    JSON, and the retried ones say so (``X-ProcTex-Retried``)."""
    import shutil
    import urllib.error
    import urllib.request

    from ray import serve

    root = tmp_path / "families"
    for name in ("mug", "cup"):
        shutil.copytree(reference.base, root / name)
    base = _serve_app(root, "proctex-kill", replicas=2)
    title = b"ServeReplica:proctex-kill:ProcTexTransfer"
    port = int(base.rsplit(":", 1)[1])
    stalled = []
    try:
        for _ in range(40):
            s = socket.create_connection(("127.0.0.1", port), timeout=10)
            s.sendall(b'POST /v1/families/mug/transfer HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: 1000\r\n\r\n{"params":')
            stalled.append(s)
        time.sleep(0.5)
        with urllib.request.urlopen(base + "/healthz", timeout=30) as r:
            assert r.status == 200
        code, _, body = _transfer(base, "cup", routed=False)
        assert code == 200 and body[:4] == b"glTF", body[:200]
        for s in stalled:  # still held: nothing answered them yet
            s.setblocking(False)
            try:
                got = s.recv(1)
            except BlockingIOError:
                got = None
            assert got is None, "a stalled body was answered already"
    finally:
        for s in stalled:
            s.close()
    answers: list[tuple[int, str, str, bytes]] = []
    started = threading.Event()

    def one(k: int) -> None:
        body = json.dumps({"params": {"radius": 0.03 + 0.0004 * k}}).encode()
        req = urllib.request.Request(f"{base}/v1/families/mug/transfer", data=body, headers={"content-type": "application/json"}, method="POST")
        started.set()
        try:
            with urllib.request.urlopen(req, timeout=180) as r:
                answers.append((r.status, r.headers.get("content-type", ""), r.headers.get("x-proctex-retried", ""), r.read()))
        except urllib.error.HTTPError as e:
            answers.append((e.code, e.headers.get("content-type", ""), e.headers.get("x-proctex-retried", ""), e.read()))

    try:
        replicas = pids_running(title)
        assert len(replicas) == 2, replicas
        with ThreadPoolExecutor(10) as pool:
            futures = [pool.submit(one, k) for k in range(50)]
            started.wait(30)
            while len(answers) < 4:  # both replicas busy, each holding queued requests
                time.sleep(0.05)
            os.kill(replicas[0], signal.SIGKILL)
            for f in futures:
                f.result()
        plain = [(code, ctype, body[:80]) for code, ctype, _, body in answers if code != 200 and "json" not in ctype]
        assert not plain, plain
        for code, ctype, _, body in answers:
            if code == 200:
                assert body[:4] == b"glTF"
            else:
                assert "error" in json.loads(body)
        codes = [a[0] for a in answers]
        retried = sum(a[2] == "1" for a in answers)
        assert len(answers) == 50 and codes.count(200) == 50 and retried >= 1, ({c: codes.count(c) for c in set(codes)}, retried)
    finally:
        serve.delete("proctex-kill")


def _front(root: Path, name: str, **args):
    """``proctex serve``'s one-hop front (workers/front.py) in a thread of this process before
    transfer replicas of ``root`` on Serve with no proxy; returns its base URL and a stop call."""
    import asyncio

    from ray import serve

    from workers.front import deploy_transfer, front_app, server

    serve.shutdown()
    serve.start(proxy_location="Disabled")
    deployed = deploy_transfer({"root": str(root), **{k: str(v) for k, v in args.items()}}, name=name)
    port = _free_port()
    srv = server(front_app(*deployed), "127.0.0.1", port)
    thread = threading.Thread(target=lambda: asyncio.run(srv.serve()), daemon=True)
    thread.start()
    deadline = time.monotonic() + 60
    while not srv.started and time.monotonic() < deadline:
        time.sleep(0.05)
    assert srv.started, "the front did not start"

    def stop() -> None:
        srv.should_exit = True
        thread.join(60)
        serve.delete(name)

    return f"http://127.0.0.1:{port}", stop


def test_the_front_holds_against_stalled_clients_and_a_replica_killed_under_load(local_ray, reference, tmp_path):
    """Issue 56: the same guarantees as the test above with ``proctex serve``'s one-hop front
    instead of Serve's proxy and the ingress deployment. 40 stalled bodies are held while the health
    route and another family's transfer are answered; 50 transfers from 10 clients with one transfer
    replica SIGKILLed under them all answer 200 (those it held retried, and say so), never plain
    text. Each answer says where its time went (Server-Timing), through the front, and which way
    it came from the replica: the side channel (``workers.sidechannel``) while both replicas
    listen, the Serve handle while one does."""
    import shutil
    import urllib.error
    import urllib.request

    from proctex.serve.timing import parse_server_timing

    root = tmp_path / "families"
    for name in ("mug", "cup"):
        shutil.copytree(reference.base, root / name)
    base, stop = _front(root, "proctex-front", replicas=2)
    port = int(base.rsplit(":", 1)[1])
    title = b"ServeReplica:proctex-front:ProcTexTransfer"
    stalled = []
    try:
        for _ in range(40):
            s = socket.create_connection(("127.0.0.1", port), timeout=10)
            s.sendall(b'POST /v1/families/mug/transfer HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: 1000\r\n\r\n{"params":')
            stalled.append(s)
        time.sleep(0.5)
        with urllib.request.urlopen(base + "/healthz", timeout=30) as r:
            assert r.status == 200
        req = urllib.request.Request(f"{base}/v1/families/cup/transfer", data=json.dumps({"params": {"radius": 0.04}}).encode(), headers={"content-type": "application/json"}, method="POST")
        with urllib.request.urlopen(req, timeout=120) as r:
            assert r.status == 200 and r.read()[:4] == b"glTF"
            stages = parse_server_timing(", ".join(r.headers.get_all("server-timing") or []))
            assert r.headers.get("x-proctex-hop") == "side-channel"  # the replicas listen on this node
        assert {"ingress", "forward", "replica", "app", "uv", "glb"} <= set(stages), stages
        for s in stalled:  # still held: nothing answered them yet
            s.setblocking(False)
            try:
                got = s.recv(1)
            except BlockingIOError:
                got = None
            assert got is None, "a stalled body was answered already"
    finally:
        for s in stalled:
            s.close()
    answers: list[tuple[int, str, str, bytes]] = []
    hops: list[str] = []

    def one(k: int) -> None:
        body = json.dumps({"params": {"radius": 0.03 + 0.0004 * k}}).encode()
        req = urllib.request.Request(f"{base}/v1/families/mug/transfer", data=body, headers={"content-type": "application/json"}, method="POST")
        try:
            with urllib.request.urlopen(req, timeout=180) as r:
                answers.append((r.status, r.headers.get("content-type", ""), r.headers.get("x-proctex-retried", ""), r.read()))
                hops.append(r.headers.get("x-proctex-hop", ""))
        except urllib.error.HTTPError as e:
            answers.append((e.code, e.headers.get("content-type", ""), e.headers.get("x-proctex-retried", ""), e.read()))

    try:
        replicas = pids_running(title)
        assert len(replicas) == 2, replicas
        with ThreadPoolExecutor(10) as pool:
            futures = [pool.submit(one, k) for k in range(50)]
            while len(answers) < 4:  # both replicas busy, each holding queued requests
                time.sleep(0.05)
            os.kill(replicas[0], signal.SIGKILL)
            for f in futures:
                f.result()
        assert not [(code, ctype, body[:80]) for code, ctype, _, body in answers if code != 200 and "json" not in ctype]
        codes = [a[0] for a in answers]
        retried = sum(a[2] == "1" for a in answers)
        assert len(answers) == 50 and codes.count(200) == 50 and retried >= 1, ({c: codes.count(c) for c in set(codes)}, retried, [body[:200] for code, _, _, body in answers if code != 200])
        assert all(body[:4] == b"glTF" for _, _, _, body in answers)
        # the side channel until the kill; then the handle while 1 of 2 replicas listens
        assert hops.count("side-channel") >= 4 and set(hops) <= {"side-channel", "serve-handle"}, hops
    finally:
        stop()


def test_the_fronts_handle_routes_on_the_servers_loop_and_serve_stops_after_it(local_ray, reference, tmp_path):
    """The front's handle (workers.front.on_this_loop) is a handle of its own whose router runs on
    the server's event loop, not on Serve's router thread; it answers, and after the front has
    stopped (its loop closed) ``serve.shutdown`` still stops Serve: Serve's cached handle was left
    alone (initialising that one on the front's loop made ``serve.shutdown`` raise "Event loop is
    closed")."""
    import asyncio
    import shutil
    import urllib.request

    from ray import serve

    from workers.front import on_this_loop

    root = tmp_path / "families"
    shutil.copytree(reference.base, root / "mug")
    base, stop = _front(root, "proctex-front-loop", replicas=1)
    try:
        req = urllib.request.Request(f"{base}/v1/families/mug/transfer", data=json.dumps({"params": {"radius": 0.04}}).encode(), headers={"content-type": "application/json"}, method="POST")
        with urllib.request.urlopen(req, timeout=120) as r:
            assert r.status == 200 and r.read()[:4] == b"glTF"
        handle = serve.get_deployment_handle("ProcTexTransfer", "proctex-front-loop")

        async def one_call() -> tuple:
            own = on_this_loop(handle)
            try:
                answer = await own.forward.remote({"method": "GET", "path": "/healthz", "headers": [], "body": b""})
            finally:
                await own.shutdown_async()
            return own, answer

        own, answer = asyncio.run(one_call())
        assert own is not handle and own.init_options._run_router_in_separate_loop is False
        assert answer["status"] == 200
    finally:
        stop()
    serve.shutdown()  # raised "Event loop is closed" when the front had taken over Serve's cached handle


def test_a_private_ray_serving_a_family_listens_on_loopback_behind_its_own_token(local_ray, reference, tmp_path):
    """Every socket this test's private Ray listens on while it serves a family is on loopback, but
    the one Ray 2.60 binds to every interface with no option (a Serve replica's gRPC server, "[::]:0"),
    and token authentication is on with a token of its own (a file of mode 0600, not the shared
    ~/.ray/auth_token): a client without it is refused."""
    import ipaddress
    import shutil
    import subprocess

    import psutil

    from workflows.build import _descendants

    root = tmp_path / "families"
    shutil.copytree(reference.base, root / "mug")
    base = _serve_app(root, "proctex-ports", replicas=1)
    assert _transfer(base, "mug", routed=False)[0] == 200
    ours = _descendants(os.getpid()) | {os.getpid()}
    wide = set()
    for c in psutil.net_connections(kind="tcp"):
        if c.status == psutil.CONN_LISTEN and c.pid in ours:
            a = ipaddress.ip_address(c.laddr.ip)
            if not (a.is_loopback or (a.version == 6 and a.ipv4_mapped is not None and a.ipv4_mapped.is_loopback)):
                wide.add(psutil.Process(c.pid).name())
    assert wide and all(name.startswith("ray::ServeReplica") for name in wide), wide
    token = Path(os.environ["RAY_AUTH_TOKEN_PATH"])
    assert os.environ["RAY_AUTH_MODE"] == "token" and token.parent != Path.home() / ".ray" and oct(token.stat().st_mode & 0o777) == "0o600"
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAY_AUTH")}
    gcs = ray.get_runtime_context().gcs_address
    done = subprocess.run([str(Path(sys.executable).parent / "ray"), "status", f"--address={gcs}"], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode != 0 and "uthentication" in done.stdout + done.stderr, (done.stdout + done.stderr)[-2000:]
