"""The transfer service without Ray: the catalog (discovery, caching, reload on rebuild) and every
HTTP route of the FastAPI app with its bad-input cases."""

import io
import json
import shutil

import numpy as np
import pytest

from proctex.family import BuildConfig, edit_group, stage_paint, stage_sample, stage_template, write_config
from proctex.service import Catalog, FamilyService, Limits, NotFound, build_stamp
from proctex.store import FamilyStore

fastapi = pytest.importorskip("fastapi")
from fastapi.testclient import TestClient  # noqa: E402

from workers.http import create_app  # noqa: E402


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    """A store root with a painted mug family (no networks: the identity mapper serves it) and a
    half-built folder that is not a family yet."""
    base = tmp_path_factory.mktemp("families")
    cfg = BuildConfig(model="mug", n_train=2, n_test=0, texture_size=32, prompt="blue ceramic").validate()
    st = FamilyStore(base / "mug")
    write_config(st, cfg)
    for stage in (stage_sample, stage_template, stage_paint):
        stage(st, cfg, log=lambda *_: None)
    (base / "notes").mkdir()
    (base / "notes" / "readme.txt").write_text("not a family")
    return base


@pytest.fixture()
def client(root):
    cat = Catalog(str(root), Limits(max_bytes=2_000_000, max_vertices=20_000, max_faces=40_000), check_every=0)
    return TestClient(create_app(lambda: cat)), cat


def _glb_ok(data: bytes) -> None:
    import trimesh

    assert data[:4] == b"glTF"
    scene = trimesh.load(io.BytesIO(data), file_type="glb")
    assert len(scene.geometry) >= 1


def test_routes(client, root):
    c, cat = client
    assert c.get("/healthz").json()["status"] == "ok"
    assert c.get("/v1/families").json() == {"families": ["mug"]}
    d = c.get("/v1/families/mug").json()
    assert d["name"] == "mug" and d["inputs"] == ["params", "mesh"] and d["prompt"] == "blue ceramic"
    assert [p["name"] for p in d["parameters"]][:2] == ["height", "radius"] and len(d["groups"]) == 2
    r = c.post("/v1/families/mug/transfer", json={"params": {"radius": 0.045}})
    assert r.status_code == 200 and r.headers["content-type"] == "model/gltf-binary"
    assert float(r.headers["x-proctex-seconds"]) > 0 and isinstance(json.loads(r.headers["x-proctex-notes"]), list)
    _glb_ok(r.content)
    # The same shape as an uploaded mesh.
    from proctex.meshio import obj_text
    from proctex.models import get_model

    shape = get_model("mug").generate({"radius": 0.045})
    r2 = c.post("/v1/families/mug/transfer", files={"mesh": ("m.obj", obj_text(shape.vertices, shape.faces).encode())}, data={"seed": "3"})
    assert r2.status_code == 200
    _glb_ok(r2.content)
    schema = c.get("/openapi.json").json()
    assert {"/healthz", "/v1/families", "/v1/families/{name}", "/v1/families/{name}/transfer"} <= set(schema["paths"])
    body = schema["paths"]["/v1/families/{name}/transfer"]["post"]["requestBody"]["content"]
    assert {"application/json", "multipart/form-data"} <= set(body)


@pytest.mark.parametrize(
    "kwargs, status, message",
    [
        ({"json": {"params": {"radius": 5}}}, 422, "radius"),
        ({"json": {"params": {"colour": 1}}}, 422, "colour"),
        ({"json": {"params": "big"}}, 422, "bad JSON body"),
        ({"content": b"{not json", "headers": {"content-type": "application/json"}}, 422, "bad JSON body"),
        ({"content": b"hello", "headers": {"content-type": "text/plain"}}, 422, "application/json"),
        ({"files": {"mesh": ("m.obj", b"this is not a mesh")}}, 422, "cannot read the mesh"),
        ({"files": {"mesh": ("m.obj", b"")}}, 422, "empty"),
        ({"files": {"mesh": ("m.xyz", b"v 0 0 0")}}, 422, "unsupported mesh type"),
        ({"files": {"other": ("m.obj", b"v 0 0 0")}}, 422, "'mesh'"),
        ({"files": {"mesh": ("m.obj", b"v 0 0 0\n" * 300_000)}}, 413, "limit"),
        ({"content": b"x" * 3_000_000, "headers": {"content-type": "application/json"}}, 413, "limit"),
    ],
)
def test_bad_requests_get_clear_json_errors(client, kwargs, status, message):
    c, _ = client
    r = c.post("/v1/families/mug/transfer", **kwargs)
    assert r.status_code == status, r.text
    assert message in r.json()["error"]


def test_unknown_families_and_mesh_limits(client, root):
    c, _ = client
    for path in ("/v1/families/nope", "/v1/families/notes", "/v1/families/.hidden"):
        r = c.get(path)
        assert r.status_code == 404 and "unknown family" in r.json()["error"]
    assert c.post("/v1/families/nope/transfer", json={"params": {}}).status_code == 404
    # A valid mesh over the face limit.
    from proctex.meshio import obj_text
    from proctex.primitives import box

    big = box((1, 1, 1))
    cat = Catalog(str(root), Limits(max_faces=5), check_every=0)
    r = TestClient(create_app(lambda: cat)).post("/v1/families/mug/transfer", files={"mesh": ("b.obj", obj_text(big.vertices, big.faces).encode())})
    assert r.status_code == 413 and "faces" in r.json()["error"]


def test_catalog_caches_and_reloads_a_rebuilt_family(root, tmp_path):
    base = tmp_path / "root"
    shutil.copytree(root / "mug", base / "mug")
    cat = Catalog(str(base), check_every=0)
    a = cat.get("mug")
    assert cat.get("mug") is a and cat.loads == 1
    stamp = build_stamp(FamilyStore(base / "mug"))
    edit_group(FamilyStore(base / "mug"), "handle", hue=120)  # an edit changes the build stamp
    assert build_stamp(FamilyStore(base / "mug")) != stamp
    b = cat.get("mug")
    assert b is not a and cat.loads == 2
    # The reloaded service shows the edit: its handle texture changed, the body did not.
    assert not np.array_equal(a.assets.textures[1], b.assets.textures[1]) and np.array_equal(a.assets.textures[0], b.assets.textures[0])
    with pytest.raises(NotFound):
        cat.get("../mug")


def test_folder_families_take_meshes_only(tmp_path, sofa_dir):
    import pyarrow as pa

    st = FamilyStore(tmp_path / "sofa")
    cfg = BuildConfig(folder=str(sofa_dir), texture_size=32).validate()
    write_config(st, cfg)
    # Three samples are enough for a painted template.
    from proctex.family import run_sample_job, sample_jobs, finish_sample_stage

    jobs = [j for j in sample_jobs(cfg) if j.split == "train"][:3]
    finish_sample_stage(st, [run_sample_job(st, cfg, j) for j in jobs])
    stage_template(st, cfg, log=lambda *_: None)
    stage_paint(st, cfg, log=lambda *_: None)
    svc = FamilyService(st, "sofa")
    d = svc.describe()
    assert d["inputs"] == ["mesh"] and len(d["parameters"]) == 4 and pa is not None
    with pytest.raises(ValueError, match="folder of meshes"):
        svc.shape_from_params({})
    data, summary = svc.transfer(svc.shape_from_mesh((sofa_dir / "inference" / "4.obj").read_bytes(), "4.obj"))
    _glb_ok(data)
    assert summary["faces"] > 1000


def test_ray_commands_reject_bad_input_before_starting_anything(tmp_path, capsys, root):
    from proctex.cli import main as core_main
    from workflows.cli import main

    for argv, message in [
        (["serve", str(tmp_path / "empty")], "no families found"),
        (["serve", str(root), "--port", "0"], "--port"),
        (["build", "--model", "mug", "--out", str(tmp_path / "b"), "--ray", "--n-train", "1"], "n_train"),
        (["build", "--model", "nosuch", "--out", str(tmp_path / "b"), "--ray"], "nosuch"),
        (["build", str(tmp_path / "missing.toml"), "--out", str(tmp_path / "b"), "--ray"], "not found"),
    ]:
        capsys.readouterr()
        assert main(argv) == 2, argv
        assert message in capsys.readouterr().err, argv
    assert not (tmp_path / "b").exists()
    # The Ray-free command names the one to use.
    assert core_main(["build", "--model", "mug", "--out", str(tmp_path / "c"), "--ray"]) == 2
    assert "workflows.cli" in capsys.readouterr().err and not (tmp_path / "c").exists()


def test_the_core_never_imports_ray():
    import pkgutil
    import subprocess
    import sys

    import proctex

    mods = [m.name for m in pkgutil.walk_packages(proctex.__path__, "proctex.") if "diffusion" not in m.name]
    code = "import importlib, sys\n" + "".join(f"importlib.import_module({m!r})\n" for m in mods) + "print('ray' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "False"
