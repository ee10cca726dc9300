"""cluster/: the manifests parse and name import paths and entrypoints that exist; the local
multi-node script starts a head + worker cluster that runs a build submitted through the Ray Jobs API."""

import importlib
import json
import os
import re
import subprocess
import time
import urllib.error
import urllib.request
import tomllib
from pathlib import Path

import pytest

yaml = pytest.importorskip("yaml")
ROOT = Path(__file__).resolve().parents[1]
CLUSTER = ROOT / "cluster"


def _import_path(path: str):
    module, _, attr = path.partition(":")
    return getattr(importlib.import_module(module), attr)


def test_manifests_parse_and_name_what_exists():
    from ray.serve.schema import ServeDeploySchema

    serve_cfg = yaml.safe_load((CLUSTER / "serve.yaml").read_text())
    ServeDeploySchema.model_validate(serve_cfg)
    for app in serve_cfg["applications"]:
        assert callable(_import_path(app["import_path"]))
    docs = [d for f in sorted((CLUSTER / "kuberay").glob("*.yaml")) for d in yaml.safe_load_all(f.read_text())]
    assert sorted(d["kind"] for d in docs) == ["RayJob", "RayJob", "RayService"]
    assert all(d["apiVersion"] == "ray.io/v1" for d in docs)
    jobs = {d["metadata"]["name"]: d for d in docs if d["kind"] == "RayJob"}
    service = next(d for d in docs if d["kind"] == "RayService")["spec"]
    inner = yaml.safe_load(service["serveConfigV2"])
    ServeDeploySchema.model_validate(inner)
    for app in inner["applications"]:
        app_builder = _import_path(app["import_path"])
        assert callable(app_builder)
        app_builder({k: v for k, v in app["args"].items()})  # the builder accepts its args (binds, does not run)
    for spec in [j["spec"]["rayClusterSpec"] for j in jobs.values()] + [service["rayClusterConfig"]]:
        assert spec["headGroupSpec"]["template"]["spec"]["containers"] and spec["workerGroupSpecs"][0]["groupName"]
        # every node reaches the S3 store with the same credentials (one Secret; no node shares a disk)
        for pod in [spec["headGroupSpec"]] + spec["workerGroupSpecs"]:
            for container in pod["template"]["spec"]["containers"]:
                assert {"secretRef": {"name": "proctex-s3"}} in container.get("envFrom", []), container["name"]
    parser = importlib.import_module("workflows.cli").build_parser()
    commands = {}
    for job in jobs.values():
        entry = job["spec"]["entrypoint"].split()
        assert entry[:3] == ["python", "-m", "workflows.cli"]
        args = parser.parse_args(entry[3:])  # every flag exists
        commands[entry[3]] = (entry, args)
    assert set(commands) == {"build", "generate"}
    entry, _ = commands["build"]
    assert "--ray" in entry
    _, gen = commands["generate"]
    assert gen.n == 10000 and gen.address == "auto" and gen.out.startswith("s3://") and not gen.no_ray
    # The job's config file is in this folder and is a valid build config.
    from proctex.store.config import BuildConfig

    assert entry[4].endswith("cluster/family.toml")
    BuildConfig.from_dict(tomllib.loads((CLUSTER / "family.toml").read_text()))
    launcher = yaml.safe_load((CLUSTER / "cluster.yaml").read_text())
    assert {"cluster_name", "provider", "head_node_type", "available_node_types"} <= set(launcher)
    assert launcher["head_node_type"] in launcher["available_node_types"]
    from ray.autoscaler._private.commands import prepare_config
    from ray.autoscaler._private.util import validate_config

    validate_config(prepare_config(launcher))  # Ray's own schema, with the provider's defaults filled in


def test_local_cluster_script_usage():
    r = subprocess.run(["bash", str(CLUSTER / "local_cluster.sh")], capture_output=True, text=True)
    assert r.returncode == 2 and "usage" in r.stderr


def _dockerfile() -> tuple[dict[str, str], list[list[str]]]:
    """cluster/Dockerfile as ``(ARG defaults, [instruction, rest] per instruction)``, continuation
    lines joined and comments dropped."""
    text = (CLUSTER / "Dockerfile").read_text()
    joined = re.sub(r"\\\n\s*", " ", "\n".join(line for line in text.splitlines() if not line.lstrip().startswith("#")))
    steps = [line.strip().split(None, 1) for line in joined.splitlines() if line.strip()]
    args = dict(rest.split("=", 1) for op, rest in steps if op == "ARG")
    return args, steps


def test_the_cluster_image_recipe_installs_this_wheel_on_the_manifests_ray():
    """The container recipe the KubeRay manifests name (it cannot be built here: checked as text):
    the official Ray image of the manifests' Ray version and of this environment's, Python 3.11, CPU;
    torch at pyproject's pin from the CPU index; the wheel `make wheel` writes, with an extra that
    exists; xatlas without threads as make setup builds it; the build config where the RayJob reads
    it; every manifest's image tagged with pyproject's version, which `make image` builds; and a
    .dockerignore that lets in what is copied and nothing else."""
    import fnmatch

    import ray

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    version = project["version"]
    args, steps = _dockerfile()
    ops = [op for op, _ in steps]
    assert ops[0] == "ARG" and ops[1] == "FROM" and ops.count("FROM") == 1
    docs = [d for f in sorted((CLUSTER / "kuberay").glob("*.yaml")) for d in yaml.safe_load_all(f.read_text())]
    specs = [d["spec"]["rayClusterSpec"] if d["kind"] == "RayJob" else d["spec"]["rayClusterConfig"] for d in docs]
    assert {s["rayVersion"] for s in specs} == {args["RAY_VERSION"]} == {ray.__version__}
    assert steps[1][1] == "rayproject/ray:${RAY_VERSION}-py311-cpu"
    torch_pin = next(d for d in project["dependencies"] if d.startswith("torch"))
    runs = [rest for op, rest in steps if op == "RUN"]
    assert f"pip install --no-cache-dir {torch_pin} --index-url https://download.pytorch.org/whl/cpu" in runs[0]  # before the wheel
    copies = [rest.split() for op, rest in steps if op == "COPY"]
    assert [c[-2:] for c in copies] == [["dist/", "/tmp/dist/"], ["cluster/family.toml", "/app/cluster/family.toml"]]
    wheel_run = next(r for r in runs if "/tmp/dist/proctex-*.whl" in r)
    extras = re.findall(r"proctex-\*\.whl\)\[([a-z,]+)\]", wheel_run)
    assert extras and set(extras[0].split(",")) <= set(project["optional-dependencies"])
    assert runs.index(wheel_run) == 1
    makefile = (ROOT / "Makefile").read_text()
    xatlas_run = next(r for r in runs if "--no-binary xatlas" in r)
    assert 'CMAKE_ARGS="-DCMAKE_CXX_FLAGS=-DXA_MULTITHREADED=0"' in xatlas_run and 'CMAKE_ARGS="-DCMAKE_CXX_FLAGS=-DXA_MULTITHREADED=0"' in makefile
    build = next(d for d in docs if d["kind"] == "RayJob" and " build " in d["spec"]["entrypoint"])
    assert "/app/cluster/family.toml" in build["spec"]["entrypoint"].split()
    images = {c["image"] for s in specs for pod in [s["headGroupSpec"], *s["workerGroupSpecs"]] for c in pod["template"]["spec"]["containers"]}
    assert images == {f"ghcr.io/proctex/proctex:{version}"}
    assert "docker build -f cluster/Dockerfile -t ghcr.io/proctex/proctex:$(VERSION) ." in makefile
    assert "-w dist" in makefile
    # .dockerignore: everything out but the wheel and the build config
    patterns = [p for p in (ROOT / ".dockerignore").read_text().splitlines() if p and not p.startswith("#")]

    def sent(path: str) -> bool:
        keep = True
        for p in patterns:
            neg = p.startswith("!")
            if fnmatch.fnmatch(path, p.lstrip("!")):
                keep = neg
        return keep

    assert sent(f"dist/proctex-{version}-py3-none-any.whl") and sent("cluster/family.toml")
    assert not any(sent(p) for p in ("README.md", "proctex/__init__.py", ".venv/bin/python", "workers/studio/node_modules/x.js", "dist/other.tar.gz"))


#: The processes of a multi-node Ray 2.60 cluster on one machine that listen on its routable address
#: or every interface, with no option to keep them on loopback (cluster/local_cluster.sh): the GCS,
#: the raylets, core workers, the dashboard's and runtime-env agents, metrics exporters.
RAY_NODE_LISTENERS = {
    "gcs_server",
    "raylet",
    "ray::IDLE",
    "ray::DashboardAgent",
    "ray::RuntimeEnvAgent",
    "python",
    "python3",
    "ray::JobSupervisor",
    "ray::_wrapped",
    "default_worker.py",
    "ray::RayTrainWorker",
}


def listeners_of(ray_tmp: str) -> list[tuple[str, int, str]]:
    """``(address, port, process name)`` of every listening TCP socket of the Ray processes of the
    cluster whose temp dir is ``ray_tmp`` (a process naming it on its command line, or holding a file
    under it or its worker nodes' ``ray_tmp-wN`` open)."""
    import psutil

    pids = set()
    for proc in psutil.process_iter(["pid", "cmdline"]):
        if any(ray_tmp in (part or "") for part in (proc.info["cmdline"] or [])):
            pids.add(proc.info["pid"])
    for fd in Path("/proc").glob("[0-9]*/fd/*"):
        try:
            if os.readlink(fd).startswith(ray_tmp):
                pids.add(int(fd.parts[2]))
        except OSError:
            continue
    out = []
    for c in psutil.net_connections(kind="tcp"):
        if c.status == psutil.CONN_LISTEN and c.pid in pids:
            try:
                name = psutil.Process(c.pid).name()
            except psutil.Error:
                name = "?"
            out.append((c.laddr.ip, c.laddr.port, name))
    return out


def loopback(address: str) -> bool:
    import ipaddress

    a = ipaddress.ip_address(address)
    return a.is_loopback or (a.version == 6 and a.ipv4_mapped is not None and a.ipv4_mapped.is_loopback)


@pytest.mark.slow
@pytest.mark.ray
def test_a_job_submitted_to_a_head_and_worker_cluster_builds_a_family(tmp_path):
    import tempfile

    from ray.job_submission import JobStatus

    from workflows.jobs import cluster_env, job_client, submit_job

    from tests.wheels import STUDIO_INDEX, build_wheel

    if not STUDIO_INDEX.is_file():
        pytest.skip("the studio is not bundled (no npm): the wheel would lack it")
    # The code reaches the nodes as a wheel in the job's runtime environment (py_modules: Ray uploads
    # it and pip-installs it on each node), as on a stock Ray cluster. These nodes already hold the
    # dependencies (this environment), so their pip takes the wheel alone (PIP_NO_DEPS), as make
    # test's wheel install does; a stock cluster's pip installs them too.
    wheel = build_wheel(tmp_path / "src", tmp_path)
    short_tmp = tempfile.mkdtemp(prefix="rayc", dir="/tmp")  # Ray's socket paths must stay short
    env = {
        **os.environ,
        "RAY_PORT": "6391",
        "DASHBOARD_PORT": "8276",
        "RAY_CLIENT_PORT": "9391",
        "RAY": str(ROOT / ".venv" / "bin" / "ray"),
        "RAY_TMP": short_tmp,
        "PROCTEX_CLUSTER_WAIT": "240",
        "PIP_NO_DEPS": "1",
        "PIP_NO_INDEX": "1",
        "PATH": f"{ROOT / '.venv' / 'bin'}{os.pathsep}{os.environ.get('PATH', '')}",
        **cluster_env(short_tmp),
    }
    env.pop("PYTHONPATH", None)
    short_tmp2 = tempfile.mkdtemp(prefix="rayd", dir="/tmp")
    env2 = {**env, "RAY_PORT": "6392", "DASHBOARD_PORT": "8277", "RAY_CLIENT_PORT": "9392", "RAY_TMP": short_tmp2, **cluster_env(short_tmp2)}

    if not Path(env["RAY"]).exists():
        pytest.skip("no .venv/bin/ray")
    script = str(CLUSTER / "local_cluster.sh")
    try:  # from here on, whatever fails (a start that timed out included): the cluster is stopped
        # the script's own bounds (PROCTEX_CLUSTER_WAIT for the CPUs, then for the job agent) end it first
        start = subprocess.run(["bash", script, "start", "1", "1"], env=env, capture_output=True, text=True, timeout=600)
        assert start.returncode == 0, start.stderr
        status = subprocess.run(["bash", script, "status"], env=env, capture_output=True, text=True, timeout=60).stdout
        assert "2.0 CPU" in status or "0.0/2.0 CPU" in status, status
        # what listens beyond loopback is only what Ray 2.60 puts on the node address of a multi-node
        # cluster (cluster/local_cluster.sh says why), and it is all behind the cluster's token
        heard = listeners_of(short_tmp)
        wide = {name for address, _, name in heard if not loopback(address)}
        assert heard and wide <= RAY_NODE_LISTENERS, (wide - RAY_NODE_LISTENERS, heard)
        assert all(loopback(address) for address, port, _ in heard if port == 8276), heard  # the Jobs API: --dashboard-host
        with urllib.request.urlopen("http://127.0.0.1:8276/api/authentication_mode", timeout=30) as r:
            assert json.loads(r.read())["authentication_mode"] == "token"
        try:
            urllib.request.urlopen("http://127.0.0.1:8276/api/jobs/", timeout=30)
            raise AssertionError("the Jobs API answered a request without the token")
        except urllib.error.HTTPError as exc:
            assert exc.code == 401, exc.code
        assert oct(os.stat(Path(short_tmp) / "auth_token").st_mode & 0o777) == "0o600"
        cfg = tmp_path / "family.json"
        cfg.write_text(
            json.dumps(
                {
                    "model": "mug",
                    "n_train": 3,
                    "n_test": 0,
                    "corr_points": 200,
                    "cage_iterations": 20,
                    "texture_size": 32,
                    "train": {"iterations": 10, "eval_every": 5, "context_points": 64, "query_points": 32, "shapes_per_batch": 2},
                }
            )
        )
        out = tmp_path / "mug"
        client = job_client("http://127.0.0.1:8276", token_path=cluster_env(short_tmp)["RAY_AUTH_TOKEN_PATH"])
        # start returned after the Jobs API ran its no-op readiness job
        ready = [j for j in client.list_jobs() if (j.submission_id or "").startswith("proctex-ready")]
        assert len(ready) == 1 and ready[0].status == JobStatus.SUCCEEDED and ready[0].metadata == {"proctex": "readiness check"}
        # the nodes run tasks at normal priority (Ray's default niceness 15 starved them on a busy machine)
        niceness = submit_job(client, f"{ROOT / '.venv' / 'bin' / 'python'} -c 'import ray, os; ray.init(); print(\"nice\", ray.get(ray.remote(lambda: os.nice(0)).remote()))'")
        deadline = time.time() + 300
        while time.time() < deadline and not client.get_job_status(niceness).is_terminal():
            time.sleep(1)
        assert "nice 0" in client.get_job_logs(niceness), client.get_job_logs(niceness)[-2000:]
        # From a folder outside this tree, without PYTHONPATH: the driver and its tasks import the
        # wheel's copy that the runtime environment installed, and the build runs on it.
        python, here = ROOT / ".venv" / "bin" / "python", tmp_path / "job"
        here.mkdir()
        runtime = {"py_modules": [str(wheel)]}
        probe = "import json, ray, proctex; ray.init(); print('where', json.dumps([proctex.__file__, proctex.__version__, ray.get(ray.remote(lambda: __import__('proctex').__file__).remote())]))"
        where = submit_job(client, f'cd {here} && {python} -c "{probe}"', runtime_env=runtime)
        job = submit_job(client, f"cd {here} && {python} -m workflows.cli build {cfg} --out {out} --ray auto --train-workers 2 --quiet", runtime_env=runtime)
        deadline = time.time() + 420
        while time.time() < deadline and not all(client.get_job_status(j).is_terminal() for j in (where, job)):
            time.sleep(2)
        where_logs = client.get_job_logs(where)
        assert client.get_job_status(where) == JobStatus.SUCCEEDED, where_logs[-3000:]
        driver, version, task = json.loads(where_logs.split("where ", 1)[1].splitlines()[0])
        project_version = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
        assert version == project_version and "runtime_resources" in driver and "runtime_resources" in task, (driver, task)
        assert not Path(driver).is_relative_to(ROOT) and not Path(task).is_relative_to(ROOT)
        logs = client.get_job_logs(job)
        assert client.get_job_status(job) == JobStatus.SUCCEEDED, logs[-3000:]
        state = json.loads((out / "family.json").read_text())
        assert all(state["stages"][s]["state"] == "done" for s in ("sample", "template", "paint", "pairs", "train"))
        assert sorted(p.name for p in (out / "models").iterdir()) == ["group_0.pt", "group_1.pt"]
        assert "on Ray" in logs
        # A second cluster beside it (its own ports and folder) starts, and its Jobs API takes jobs:
        # with Ray's fixed agent port 52365 the second head's job agent could not listen, so its
        # start waited out PROCTEX_CLUSTER_WAIT on "No available agent" and failed.
        second = subprocess.run(["bash", script, "start", "0", "1"], env=env2, capture_output=True, text=True, timeout=600)
        assert second.returncode == 0, second.stderr[-3000:]
        second_client = job_client("http://127.0.0.1:8277", token_path=cluster_env(short_tmp2)["RAY_AUTH_TOKEN_PATH"])  # a token of its own
        assert [j.status for j in second_client.list_jobs()] == [JobStatus.SUCCEEDED]
        assert client.get_job_status(job) == JobStatus.SUCCEEDED  # the first one still answers
    finally:
        subprocess.run(["bash", script, "stop"], env=env2, capture_output=True, timeout=120)
        subprocess.run(["bash", script, "stop"], env=env, capture_output=True, timeout=120)
        import shutil

        shutil.rmtree(short_tmp, ignore_errors=True)
        shutil.rmtree(short_tmp2, ignore_errors=True)
