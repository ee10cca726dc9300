"""The transfer service without Ray: the catalog (discovery, caching, reload on rebuild) and every
HTTP route of the FastAPI app with its bad-input cases."""

import io
import json
import shutil

import numpy as np
import pytest

from proctex.build.pipeline import stage_paint
from proctex.build.pipeline import stage_sample
from proctex.build.pipeline import stage_template
from proctex.serve.catalog import Catalog
from proctex.serve.edits import edit_group
from proctex.serve.service import FamilyService, Limits, NotFound
from proctex.store.config import BuildConfig
from proctex.store.layout import FamilyStore
from proctex.store.state import build_stamp, write_config

fastapi = pytest.importorskip("fastapi")
from fastapi.testclient import TestClient  # noqa: E402

from workers.http import create_app  # noqa: E402


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    """A store root with a painted mug family (no networks: the identity mapper serves it) and a
    half-built folder that is not a family yet."""
    base = tmp_path_factory.mktemp("families")
    cfg = BuildConfig.from_dict(dict(model="mug", n_train=2, n_test=0, texture_size=32, prompt="blue ceramic")).validate()
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
    assert c.get("/v1/families").json() == {"families": ["mug"], "health": {"mug": "ok"}}
    d = c.get("/v1/families/mug").json()
    assert d["name"] == "mug" and d["inputs"] == ["params", "mesh"] and d["prompt"] == "blue ceramic"
    assert [p["name"] for p in d["parameters"]][:2] == ["height", "radius"] and len(d["groups"]) == 2
    r = c.post("/v1/families/mug/transfer", json={"params": {"radius": 0.045}})
    assert r.status_code == 200 and r.headers["content-type"] == "model/gltf-binary"
    assert float(r.headers["x-proctex-seconds"]) > 0 and isinstance(json.loads(r.headers["x-proctex-notes"]), list)
    _glb_ok(r.content)
    # The same shape as an uploaded mesh.
    from proctex.geometry.meshio import obj_text
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
        ({"files": {"mesh": ("m.obj", b"v 0 0 0")}, "data": {"edits": "{nope"}}, 422, "'edits' field must be JSON"),
        ({"files": {"mesh": ("m.obj", b"v 0 0 0")}, "data": {"edits": '{"lid": {"hue": 5}}'}}, 422, "unknown group 'lid'"),
        ({"files": {"mesh": ("m.obj", b"v 0 0 0\n" * 300_000)}}, 413, "limit"),
        ({"content": b"x" * 3_000_000, "headers": {"content-type": "application/json"}}, 413, "limit"),
        ({"json": {"params": {}, "seed": True}}, 422, "bad JSON body"),  # was taken as seed 1
        ({"json": {"params": {}, "seed": 1.5}}, 422, "bad JSON body"),
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
    from proctex.geometry.meshio import obj_text
    from proctex.geometry.primitives import box

    big = box((1, 1, 1))
    cat = Catalog(str(root), Limits(max_faces=5), check_every=0)
    r = TestClient(create_app(lambda: cat)).post("/v1/families/mug/transfer", files={"mesh": ("b.obj", obj_text(big.vertices, big.faces).encode())})
    assert r.status_code == 413 and "faces" in r.json()["error"]


def test_a_family_load_reads_family_json_once_and_decodes_no_png(root, monkeypatch):
    """The state record is read once and passed on (stamp, config, template, networks), and the
    template's PNGs are kept as stored: nothing decoded or encoded until a transfer needs a texture."""
    import PIL.Image

    from proctex.build import pairs
    from proctex.store.layout import StoreLayout
    from proctex.transfer.assets import texture_hw

    reads, opened, saved = [], [], []
    real_read, real_open, real_save = FamilyStore.read_json, PIL.Image.open, PIL.Image.Image.save
    monkeypatch.setattr(FamilyStore, "read_json", lambda self, rel: reads.append(rel) or real_read(self, rel))
    monkeypatch.setattr(PIL.Image, "open", lambda *a, **k: opened.append(a) or real_open(*a, **k))
    monkeypatch.setattr(PIL.Image.Image, "save", lambda self, *a, **k: saved.append(a) or real_save(self, *a, **k))
    store = FamilyStore(root / "mug")
    svc = FamilyService(store)
    assert reads.count(StoreLayout.STATE) == 1, reads
    assert opened == [] and saved == [], "a service load decoded or encoded a PNG"
    labels = [g["label"] for g in real_read(store, StoreLayout.PAINT)["groups"]]
    assert svc.assets.png == [(root / "mug" / StoreLayout.texture(g, label)).read_bytes() for g, label in enumerate(labels)]
    assert texture_hw(svc.assets, 0) == (32, 32) and opened == []  # sizes from the PNG header
    assert svc.assets.textures[0].shape == (32, 32, 3) and len(opened) == 1  # decoded where first used, once
    assert svc.assets.textures[0] is svc.assets.textures[0] and len(opened) == 1
    assert saved == []
    reads.clear()
    cat = Catalog(str(root), check_every=0)
    assert cat.get("mug").stamp == svc.stamp and reads.count(StoreLayout.STATE) == 1, reads
    pairs.cached_assets(store)  # the Ray workers' template cache keys on the same version
    assert [key[1] for key in pairs._ASSETS] == [svc.stamp]


def test_a_request_finds_the_shapes_parts_once(root, monkeypatch):
    """The parts (connected components) of a requested shape are found once: the limit check,
    the transfer and the bake share them (the count can fail: a second shape counts again)."""
    from proctex.geometry import parts

    svc = FamilyService(FamilyStore(root / "mug"))
    calls = []
    real = parts.connected_parts
    monkeypatch.setattr(parts, "connected_parts", lambda *a, **k: calls.append(1) or real(*a, **k))
    shape = svc.shape_from_params({})
    answer, _ = svc.textured(shape, bake_size=64)
    assert answer.data[:4] == b"glTF" and len(calls) == 1
    svc.textured(svc.shape_from_params({}))
    assert len(calls) == 2


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


def test_a_held_family_is_answered_at_once_only_while_its_check_is_not_due(root, tmp_path):
    """``Catalog.fresh`` (what an event loop may ask without a thread): the held service while its
    stamp was checked less than ``check_every`` ago; None before the first load, once the check is
    due, for an unknown name, and while another thread holds the catalog (it never waits)."""
    import threading

    base = tmp_path / "root"
    shutil.copytree(root / "mug", base / "mug")
    cat = Catalog(str(base), check_every=3600)
    assert cat.fresh("mug") is None  # not loaded yet: get() loads it, in a thread
    a = cat.get("mug")
    assert cat.fresh("mug") is a and cat.fresh("cup") is None
    held, release = threading.Event(), threading.Event()
    t = threading.Thread(target=lambda: cat._lock.acquire() and (held.set(), release.wait(10), cat._lock.release()))
    t.start()
    held.wait(10)
    assert cat.fresh("mug") is None  # another thread holds the catalog: not waited for
    release.set()
    t.join(10)
    assert cat.fresh("mug") is a
    cat.check_every = 0  # the check is due at once: the stamp must be read again, by get()
    assert cat.fresh("mug") is None and cat.get("mug") is a


def test_folder_families_take_meshes_only(tmp_path, sofa_dir):
    import pyarrow as pa

    st = FamilyStore(tmp_path / "sofa")
    cfg = BuildConfig.from_dict(dict(folder=str(sofa_dir), texture_size=32)).validate()
    write_config(st, cfg)
    # Three samples are enough for a painted template.
    from proctex.build.sample import finish_sample_stage, run_sample_job, sample_jobs
    from proctex.store.state import mark_stage

    jobs = [j for j in sample_jobs(cfg) if j.split == "train"][:3]
    mark_stage(st, "sample", **finish_sample_stage(st, [run_sample_job(st, cfg, j) for j in jobs]))  # what the pipeline records
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
    import socket

    from proctex.cli import main as core_main
    from workflows.cli import main

    taken = socket.socket()
    taken.bind(("127.0.0.1", 0))
    taken.listen()
    busy = str(taken.getsockname()[1])
    for argv, message in [
        (["serve", str(tmp_path / "empty")], "no families found"),
        (["serve", str(root), "--port", "0"], "--port"),
        (["serve", str(root), "--port", busy], f"cannot listen on 127.0.0.1:{busy}"),  # the front's port, said before Ray starts
        (["serve", str(root), "--host", "192.0.2.1"], "cannot listen on 192.0.2.1:8000"),  # an address not on this machine (TEST-NET-1)
        (["build", "--model", "mug", "--out", str(tmp_path / "b"), "--ray", "--n-train", "1"], "n_train"),
        (["build", "--model", "nosuch", "--out", str(tmp_path / "b"), "--ray"], "nosuch"),
        (["build", str(tmp_path / "missing.toml"), "--out", str(tmp_path / "b"), "--ray"], "not found"),
    ]:
        capsys.readouterr()
        assert main(argv) == 2, argv
        assert message in capsys.readouterr().err, argv
    assert not (tmp_path / "b").exists()
    taken.close()
    # The library's command line has no Ray option (the Ray layer adds them): --ray is unknown there.
    with pytest.raises(SystemExit) as exc:
        core_main(["build", "--model", "mug", "--out", str(tmp_path / "c"), "--ray"])
    assert exc.value.code == 2 and "unrecognized arguments: --ray" in capsys.readouterr().err and not (tmp_path / "c").exists()


def test_the_library_command_line_never_mentions_ray_and_the_ray_layer_adds_to_it():
    """proctex.cli's parser declares no Ray option and no help of it says Ray (one command registry:
    workflows.cli takes the library's commands and adds its own options and commands); the installed
    command has every option of the library's, and the Ray ones."""
    import re

    from proctex.cli.app import build_parser as core_parser
    from workflows.cli import build_parser as ray_parser

    core, full = core_parser(), ray_parser()
    said = [
        (name, a.option_strings, a.help) for name, sp in core.subparsers.choices.items() for a in sp._actions if re.search(r"\bray\b", " ".join(a.option_strings) + " " + (a.help or ""), flags=re.I)
    ]
    said += [("command", a.dest, a.help) for a in core.subparsers._choices_actions if re.search(r"\bRay\b", a.help or "")]
    assert said == []
    options = lambda p, name: {o for a in p.subparsers.choices[name]._actions for o in a.option_strings}  # noqa: E731
    for name in core.subparsers.choices:
        assert options(core, name) <= options(full, name), name
    assert options(full, "build") - options(core, "build") == {"--ray", "--train-workers", "--max-in-flight"}
    assert options(full, "generate") - options(core, "generate") == {"--no-ray", "--concurrency", "--cpus", "--address"}
    assert {"serve", "screenshot"} <= set(full.subparsers.choices) - set(core.subparsers.choices)


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


def test_the_command_line_the_http_app_and_the_ingress_start_without_torch():
    """What starts often stays light: the ``proctex`` command's parser, the HTTP app and the Serve
    ingress import no torch (a family's service imports it when it loads one); the check sees a
    module that does."""
    import subprocess
    import sys

    def imports_torch(module: str) -> bool:
        out = subprocess.run([sys.executable, "-c", f"import sys, {module}; print('torch' in sys.modules)"], capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stderr[-2000:]
        return out.stdout.strip() == "True"

    assert imports_torch("proctex.correspond.mvc")
    for module in ("proctex.cli.app", "workflows.cli", "workers.http", "workers.ingress", "proctex.serve.catalog"):
        assert not imports_torch(module), module


# ------------------------------------------------------------------------------- studio routes
def test_the_studio_page_and_its_assets_are_served_safely(root, tmp_path):
    cat = Catalog(str(root), check_every=0)
    dist = tmp_path / "studio" / "dist"
    (tmp_path / "secret.txt").write_text("outside the bundle")
    (dist / "sub").mkdir(parents=True)
    (dist / "index.html").write_text("<!doctype html><title>ProcTex studio</title><canvas id=canvas></canvas>")
    (dist / "main.js").write_text("console.log('studio')")
    (dist / "style.css").write_text("body {}")
    (dist / "sub" / "a.txt").write_text("nested")
    (dist / ".env").write_text("hidden")
    c = TestClient(create_app(lambda: cat, studio_dir=dist))
    r = c.get("/")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html") and "ProcTex studio" in r.text
    r = c.get("/studio/main.js")
    assert r.status_code == 200 and "javascript" in r.headers["content-type"] and r.text == "console.log('studio')"
    assert c.get("/studio/style.css").headers["content-type"].startswith("text/css")
    assert c.get("/studio/sub/a.txt").text == "nested"
    for path in (
        "/studio/nope.js",
        "/studio/",
        "/studio/sub",
        "/studio/.env",
        "/studio/../secret.txt",
        "/studio/%2e%2e/secret.txt",
        "/studio/..%2fsecret.txt",
        "/studio/sub/../../secret.txt",
        "/studio/%2Fetc%2Fpasswd",
        "/studio//etc/passwd",
    ):
        r = c.get(path)
        assert r.status_code == 404, (path, r.status_code, r.text[:100])
        assert "outside" not in r.text and "root:" not in r.text
        if r.headers["content-type"].startswith("application/json"):
            assert "error" in r.json()
    assert "no studio asset" in c.get("/studio/nope.js").json()["error"]
    # Not built: a clear page naming the command that builds it; the API still works.
    c2 = TestClient(create_app(lambda: cat, studio_dir=tmp_path / "missing"))
    r = c2.get("/")
    assert r.status_code == 503 and "make setup" in r.text and r.headers["content-type"].startswith("text/html")
    assert c2.get("/studio/main.js").status_code == 404
    assert c2.get("/v1/families").json()["families"] == ["mug"]


def _png_array(data: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))


def _glb_parts(data: bytes):
    """(geometry arrays per primitive, {image name: PNG bytes}) of a GLB."""
    import pygltflib

    g = pygltflib.GLTF2().load_from_bytes(data)
    blob = g.binary_blob()

    def view(i):
        bv = g.bufferViews[i]
        return blob[bv.byteOffset or 0 : (bv.byteOffset or 0) + bv.byteLength]

    geometry = []
    for prim in g.meshes[0].primitives:
        for acc in (prim.attributes.POSITION, prim.attributes.TEXCOORD_0, prim.indices):
            geometry.append(None if acc is None else view(g.accessors[acc].bufferView))
    return geometry, {im.name: view(im.bufferView) for im in g.images}


def test_transfers_take_non_destructive_edits(client, root):
    from proctex.texture.edit import rgb_to_hsv

    c, cat = client
    st = FamilyStore(root / "mug")
    stored = {0: st.read_bytes("template/group_0_body.png"), 1: st.read_bytes("template/group_1_handle.png")}
    # Thumbnails: no edit and a zero hue shift give the stored texture itself (32 px: never enlarged).
    t0 = c.get("/v1/families/mug/groups/body/texture.png")
    assert t0.status_code == 200 and t0.headers["content-type"] == "image/png" and t0.content == stored[0]
    assert c.get("/v1/families/mug/groups/0/texture.png?hue=0&saturation=1&value=1").content == stored[0]
    assert _png_array(c.get("/v1/families/mug/groups/0/texture.png?size=16").content).shape == (16, 16, 3)
    t180 = c.get("/v1/families/mug/groups/body/texture.png?hue=180")
    a0, a180 = _png_array(stored[0]) / 255, _png_array(t180.content) / 255
    hsv0, hsv180 = rgb_to_hsv(a0), rgb_to_hsv(a180)
    sat = hsv0[..., 1] > 0.2
    assert sat.mean() > 0.5 and np.median((hsv180[..., 0][sat] - hsv0[..., 0][sat]) * 360 % 360) == pytest.approx(180, abs=2)
    assert np.abs(hsv180[..., 2] - hsv0[..., 2]).max() <= 1.5 / 255  # value is kept
    # The GLB: the body's embedded texture is the edited one, the handle's and the geometry are unchanged.
    body = {"params": {"radius": 0.045}}
    plain = c.post("/v1/families/mug/transfer", json=body).content
    zero = c.post("/v1/families/mug/transfer", json={**body, "edits": {"body": {"hue": 0}}}).content
    assert zero == plain
    r = c.post("/v1/families/mug/transfer", json={**body, "edits": {"body": {"hue": 180}}})
    assert r.status_code == 200, r.text
    _glb_ok(r.content)
    geo0, img0 = _glb_parts(plain)
    geo1, img1 = _glb_parts(r.content)
    assert geo1 == geo0 and set(img1) == {f"{g}{k}" for g in ("body", "handle") for k in ("", "_orm", "_normal")}
    assert {k: img0[k] for k in ("body", "handle")} == {"body": stored[0], "handle": stored[1]}
    assert img1["body_orm"] == img0["body_orm"] and img1["body_normal"] == img0["body_normal"]  # a hue shift leaves the maps
    assert img1["handle"] == stored[1] and img1["body"] == t180.content
    # Index or label, JSON or multipart: the same GLB; a repeated edit comes from the cache.
    svc = cat.get("mug")
    hits = svc.edit_stats["hits"]
    assert c.post("/v1/families/mug/transfer", json={**body, "edits": {"0": {"hue": 180}}}).content == r.content
    assert svc.edit_stats["hits"] > hits
    from proctex.geometry.meshio import obj_text
    from proctex.models import get_model

    shape = get_model("mug").generate({"radius": 0.045})
    files = {"mesh": ("m.obj", obj_text(shape.vertices, shape.faces).encode())}
    rm = c.post("/v1/families/mug/transfer", files=files, data={"edits": json.dumps({"handle": {"hue": 90, "saturation": 0.5}})})
    assert rm.status_code == 200, rm.text
    _, imgm = _glb_parts(rm.content)
    assert imgm["body"] == stored[0] and imgm["handle"] == c.get("/v1/families/mug/groups/1/texture.png?hue=90&saturation=0.5").content
    # A re-paint with a prompt, then the hue shift, as the thumbnail shows it.
    rp = c.post("/v1/families/mug/transfer", json={**body, "edits": {"handle": {"prompt": "green plastic", "hue": 30}}})
    thumb = c.get("/v1/families/mug/groups/handle/texture.png", params={"prompt": "green plastic", "hue": "30"}).content
    assert _glb_parts(rp.content)[1]["handle"] == thumb and thumb != stored[1]


@pytest.mark.parametrize(
    "edits, message",
    [
        ({"seat": {"hue": 10}}, "unknown group 'seat'"),
        ({"7": {"hue": 10}}, "unknown group '7'"),
        ({"body": {"hue": float("nan")}}, "hue must be a finite number"),
        ({"body": {"hue": float("inf")}}, "hue must be a finite number"),
        ({"body": {"hue": 400}}, "hue must be in [-360, 360]"),
        ({"body": {"saturation": -0.5}}, "saturation must be in [0, 4]"),
        ({"body": {"value": 9}}, "value must be in [0, 4]"),
        ({"body": {"value": "bright"}}, "value must be a number"),
        ({"body": {"hue": True}}, "hue must be a number"),
        ({"body": {"prompt": "x" * 201}}, "over the limit of 200"),
        ({"body": {"prompt": 5}}, "prompt must be a string"),
        ({"body": {"hu": 5}}, "unknown edit field(s) 'hu'"),
        ({"body": 180}, "an edit must be a JSON object"),
        ({"body": {"hue": 10}, "0": {"hue": 20}}, "edited twice"),
        ([{"hue": 10}], "bad JSON body"),
    ],
)
def test_bad_edits_get_clear_json_errors(client, edits, message):
    c, _ = client
    body = json.dumps({"params": {}, "edits": edits})  # json.dumps writes NaN / Infinity, which the server reads
    r = c.post("/v1/families/mug/transfer", content=body.encode(), headers={"content-type": "application/json"})
    assert r.status_code == 422, r.text
    assert message in r.json()["error"]


def test_bad_texture_requests_get_clear_json_errors(client):
    c, _ = client
    for path, status, message in [
        ("/v1/families/mug/groups/seat/texture.png", 404, "unknown group 'seat'"),
        ("/v1/families/mug/groups/2/texture.png", 404, "unknown group '2'"),
        ("/v1/families/nope/groups/0/texture.png", 404, "unknown family"),
        ("/v1/families/mug/groups/0/texture.png?size=0", 422, "size must be an integer in [8, 1024]"),
        ("/v1/families/mug/groups/0/texture.png?size=big", 422, "size must be an integer"),
        ("/v1/families/mug/groups/0/texture.png?size=4096", 422, "size must be an integer"),
        ("/v1/families/mug/groups/0/texture.png?hue=nan", 422, "hue must be a finite number"),
        ("/v1/families/mug/groups/0/texture.png?hue=-inf", 422, "hue must be a finite number"),
        ("/v1/families/mug/groups/0/texture.png?saturation=-1", 422, "saturation must be in [0, 4]"),
        ("/v1/families/mug/groups/0/texture.png?value=x", 422, "value must be a number"),
        ("/v1/families/mug/groups/0/texture.png?prompt=" + "y" * 300, 422, "over the limit"),
    ]:
        r = c.get(path)
        assert r.status_code == status, (path, r.text)
        assert message in r.json()["error"], (path, r.json())


def test_edits_persist_into_the_family(root, tmp_path):
    base = tmp_path / "root"
    shutil.copytree(root / "mug", base / "mug")
    cat = Catalog(str(base), check_every=60)  # a long check period: the edit route invalidates the cache itself
    c = TestClient(create_app(lambda: cat, edit_token="s3cret-token"), headers={"X-ProcTex-Token": "s3cret-token"})
    st = FamilyStore(base / "mug")
    body = {"params": {"height": 0.1}}
    preview = c.post("/v1/families/mug/transfer", json={**body, "edits": {"body": {"hue": 180}}}).content
    preview_handle = c.get("/v1/families/mug/groups/handle/texture.png?prompt=red%20brick").content
    before = c.post("/v1/families/mug/transfer", json=body).content
    stamp = c.get("/v1/families/mug").json()["stamp"]
    # Bad edits change nothing.
    for payload, status, message in [
        ({"group": "seat", "hue": 10}, 422, "unknown group"),
        ({"group": 0}, 422, "no edit given"),
        ({"group": 0, "hue": 0, "saturation": 1}, 422, "no edit given"),
        ({"hue": 10}, 422, '"group"'),
        ({"group": 0, "hue": float("nan")}, 422, "finite"),
        ({"group": 0, "saturation": 7}, 422, "saturation must be in [0, 4]"),
        ({"group": 0, "prompt": "z" * 500}, 422, "over the limit"),
        ({"group": 0, "logo": "/etc/passwd"}, 422, "unknown edit field(s) 'logo'"),
        ([1, 2], 422, "JSON object"),
    ]:
        r = c.post("/v1/families/mug/edits", content=json.dumps(payload).encode(), headers={"content-type": "application/json"})
        assert r.status_code == status and message in r.json()["error"], (payload, r.text)
    r = c.post("/v1/families/mug/edits", content=b"{oops", headers={"content-type": "application/json"})
    assert r.status_code == 422 and "bad JSON body" in r.json()["error"]
    assert c.post("/v1/families/nope/edits", json={"group": 0, "hue": 5}).status_code == 404
    assert "edits" not in st.read_json("template/paint.json") and c.get("/v1/families/mug").json()["stamp"] == stamp
    assert c.post("/v1/families/mug/transfer", json=body).content == before
    # A hue shift: every later transfer carries it, exactly as its preview showed.
    r = c.post("/v1/families/mug/edits", json={"group": "body", "hue": 180})
    assert r.status_code == 200, r.text
    out = r.json()
    assert {k: out["edit"][k] for k in ("group", "hsv", "version")} == {"group": 0, "hsv": [180.0, 1.0, 1.0], "version": 1}
    assert out["family"] == "mug" and out["stamp"] != stamp
    after = c.post("/v1/families/mug/transfer", json=body).content
    assert after != before and after == preview
    d = c.get("/v1/families/mug").json()
    assert d["stamp"] == out["stamp"] and d["edits"] == 1
    # A re-paint of the handle by prompt, the same texture as its thumbnail preview.
    r = c.post("/v1/families/mug/edits", json={"group": 1, "prompt": "red brick"})
    assert r.status_code == 200 and {k: r.json()["edit"][k] for k in ("group", "prompt", "version")} == {"group": 1, "prompt": "red brick", "version": 2}
    assert st.read_bytes("template/group_1_handle.png") == preview_handle
    assert c.get("/v1/families/mug/groups/1/texture.png").content == preview_handle
    d = c.get("/v1/families/mug").json()
    assert d["groups"][1]["prompt"] == "red brick" and d["edits"] == 2 and cat.loads == 3
    _, imgs = _glb_parts(c.post("/v1/families/mug/transfer", json=body).content)
    assert imgs["handle"] == preview_handle
    # Undo the last edit, then all of them: the family answers as before any edit.
    r = c.delete("/v1/families/mug/edits/last")
    assert r.status_code == 200 and r.json()["undone"][0]["version"] == 2
    assert c.post("/v1/families/mug/transfer", json=body).content == after
    assert c.delete("/v1/families/mug/edits").status_code == 200
    assert c.post("/v1/families/mug/transfer", json=body).content == before
    assert c.delete("/v1/families/mug/edits/last").status_code == 409  # nothing left to undo


def test_stored_edits_need_the_token_a_json_body_and_the_current_stamp(root, tmp_path):
    base = tmp_path / "root"
    shutil.copytree(root / "mug", base / "mug")
    cat = Catalog(str(base), check_every=0)
    read_only = TestClient(create_app(lambda: cat))
    r = read_only.post("/v1/families/mug/edits", json={"group": 0, "hue": 10})
    assert r.status_code == 403 and "read-only" in r.json()["error"]
    assert read_only.get("/v1/families/mug").json()["edits_enabled"] is False
    c = TestClient(create_app(lambda: cat, edit_token="s3cret-token"))
    assert c.get("/v1/families/mug").json()["edits_enabled"] is True
    for headers in ({}, {"X-ProcTex-Token": "wrong"}, {"Authorization": "Bearer nope"}):
        assert c.post("/v1/families/mug/edits", json={"group": 0, "hue": 10}, headers=headers).status_code == 401
    ok = {"X-ProcTex-Token": "s3cret-token"}
    r = c.post("/v1/families/mug/edits", content=b'{"group": 0, "hue": 10}', headers={**ok, "content-type": "text/plain"})
    assert r.status_code == 415  # what a cross-site form could send
    stamp = c.get("/v1/families/mug").json()["stamp"]
    assert c.post("/v1/families/mug/edits", json={"group": 0, "hue": 10}, headers={**ok, "If-Match": stamp}).status_code == 200
    r = c.post("/v1/families/mug/edits", json={"group": 0, "hue": 10}, headers={**ok, "If-Match": stamp})
    assert r.status_code == 409 and "changed since" in r.json()["error"]  # made against the old stamp
    assert c.post("/v1/families/mug/edits", json={"group": 0, "value": 0.0}, headers={"Authorization": "Bearer s3cret-token"}).status_code == 200
    assert len(FamilyStore(base / "mug").read_json("template/paint.json")["edits"]) == 2
    assert c.delete("/v1/families/mug/edits", headers=ok).json()["undone"][0]["hsv"][2] == 0.0  # a blackened texture comes back


def test_a_change_answers_its_own_version_read_under_its_lock(root, tmp_path, monkeypatch):
    """One version value (issue 55): an edit, an undo or a new look answers the family's stamp read
    under the edit lock it was written under, so a client that conditions its next change on it is
    refused when another change landed in between. The HTTP routes read the stamp after the lock
    (a change landing between answered the newer stamp, and a conditional change built on it would
    have overwritten that change unseen). Here another edit lands right after each lock is let go."""
    import contextlib

    from proctex.serve import edits
    from proctex.store.state import build_stamp

    base = tmp_path / "root"
    shutil.copytree(root / "mug", base / "mug")
    st = FamilyStore(base / "mug")
    real, inside = edits.edit_lock, []

    @contextlib.contextmanager
    def lock_then_a_neighbour(store, *a, **k):
        with real(store, *a, **k):
            yield
        if not inside and not k.get("shared"):  # the lock is free: another client's edit lands now
            inside.append(1)
            try:
                edits.edit_group(store, 1, hue=5)
            finally:
                inside.pop()

    monkeypatch.setattr(edits, "edit_lock", lock_then_a_neighbour)
    cat = Catalog(str(base), check_every=0)
    c = TestClient(create_app(lambda: cat, edit_token="t0ken"))
    ok = {"X-ProcTex-Token": "t0ken"}
    for send in (lambda: c.post("/v1/families/mug/edits", json={"group": 0, "hue": 10}, headers=ok), lambda: c.delete("/v1/families/mug/edits/last", headers=ok)):
        r = send()
        assert r.status_code == 200, r.text
        answered = r.json()["stamp"]
        assert answered != build_stamp(st)  # the neighbour's edit came after this change
        refused = c.post("/v1/families/mug/edits", json={"group": 0, "hue": 20}, headers={**ok, "If-Match": answered})
        assert refused.status_code == 409 and "changed since" in refused.json()["error"]
    monkeypatch.setattr(edits, "edit_lock", real)
    r = c.post("/v1/families/mug/edits", json={"group": 0, "hue": 10}, headers=ok)  # nobody in between: the stamp is the family's
    assert r.json()["stamp"] == build_stamp(st) == c.get("/v1/families/mug").json()["stamp"]
    assert c.post("/v1/families/mug/edits", json={"group": 0, "hue": 20}, headers={**ok, "If-Match": r.json()["stamp"]}).status_code == 200


def test_describe_reads_no_store_file_and_describes_the_version_loaded(root, tmp_path, monkeypatch):
    """describe() (every GET of a family) answers from what the service read when it loaded, under
    the same lock as its textures: no store file is read per call, and an edit stored meanwhile (which
    the catalog answers by loading the family again) does not half-show in the old service's answer."""
    base = tmp_path / "root"
    shutil.copytree(root / "mug", base / "mug")
    st = FamilyStore(base / "mug")
    svc = FamilyService(st, "mug")
    first = svc.describe()
    view = svc.look_view(None)
    assert view is svc
    edit_group(st, 0, hue=30)  # stored after the service loaded
    read = []
    for name in ("read_json", "read_bytes", "exists", "list", "read_table", "read_arrays"):
        if hasattr(st, name):
            monkeypatch.setattr(st, name, lambda *a, _n=name, **k: read.append(_n))
    again = svc.describe()
    assert read == [] and again == first and again["edits"] == 0 and again["stamp"] == svc.stamp
    again["groups"].clear()  # a caller's changes stay its own
    assert svc.describe() == first
    monkeypatch.undo()
    fresh = FamilyService(st, "mug").describe()
    assert fresh["edits"] == 1 and fresh["stamp"] != first["stamp"]


def test_the_served_snapshot_is_immutable_and_an_edited_preview_bakes_its_edit(root, tmp_path):
    """The loaded family's images are one snapshot (issue 55: ``TemplateAssets`` kept the texture
    arrays and their PNGs apart, and an edited preview replaced the PNGs only): its fields cannot be
    reassigned, and a preview edit replaces arrays and bytes together, so a baked preview samples the
    edited colours: the same bake as after storing that edit (it baked the unedited ones)."""
    import dataclasses

    from proctex.serve.service import GroupEdit
    from tests.test_pbr import glb_material_images

    shutil.copytree(root / "mug", tmp_path / "mug")
    st = FamilyStore(tmp_path / "mug")
    svc = FamilyService(st, "mug")
    with pytest.raises(dataclasses.FrozenInstanceError):
        svc.assets.textures = svc.assets.textures
    shape = svc.shape_from_params({})
    bases = lambda answer: [m["base"] for m in glb_material_images(answer.data)]  # noqa: E731
    plain = bases(svc.textured(shape, seed=0, bake_size=64)[0])
    preview = bases(svc.textured(shape, seed=0, edits={0: GroupEdit(hue=120.0)}, bake_size=64)[0])
    edit_group(st, 0, hue=120.0)
    stored = bases(FamilyService(st, "mug").textured(shape, seed=0, bake_size=64)[0])
    assert len(plain) == len(preview) == len(stored) >= 2
    assert not np.array_equal(preview[0], plain[0]) and np.array_equal(preview[0], stored[0])
    assert all(np.array_equal(a, b) for a, b in zip(preview[1:], stored[1:]))


def test_an_edited_transfer_shares_the_families_uv_tables_and_answers_as_with_its_own(root, tmp_path, monkeypatch):
    """A per-request edit (a hue shift in the studio) textures with edited copies of the images:
    the UV lookup's tables, made when the family loaded, are shared, not made again in the request
    (~0.2 s on a sofa); the answer is the one tables made afresh for the edited copy give."""
    import dataclasses

    import proctex.transfer.uvlookup as U
    from proctex.serve.service import GroupEdit

    shutil.copytree(root / "mug", tmp_path / "mug")
    svc = FamilyService(FamilyStore(tmp_path / "mug"), "mug")
    shape = svc.shape_from_params({})
    made = []
    rooms = U.face_rooms
    monkeypatch.setattr(U, "face_rooms", lambda *a, **k: made.append(1) or rooms(*a, **k))
    edits = {0: GroupEdit(hue=120.0)}
    shared, _ = svc.transfer(shape, edits=edits, linked=True)
    assert not made  # loaded with the family
    import proctex.serve.texturing as TX

    monkeypatch.setattr(TX, "with_images", lambda a, t, p: dataclasses.replace(a, textures=t, pbr=p))  # a copy with no tables
    own, _ = svc.transfer(shape, edits=edits, linked=True)
    assert made and own == shared


def test_edit_texture_is_what_edit_group_stores(root, tmp_path):
    """The pure texture edit and the persisted one are the same code: equal results."""
    from proctex.fileio import encode_png
    from proctex.serve.edits import edit_texture

    shutil.copytree(root / "mug", tmp_path / "mug")
    st = FamilyStore(tmp_path / "mug")
    svc = FamilyService(st, "mug")
    before = _png_array(st.read_bytes("template/group_1_handle.png"))
    tex, painted, record = edit_texture(before, 1, "handle", hue=-40, saturation=1.5, value=0.8)
    assert painted is None and record == {"group": 1, "hsv": [-40, 1.5, 0.8]} and tex.dtype == np.float32
    same, _, rec0 = edit_texture(before, 1, "handle")
    assert rec0 == {"group": 1} and np.array_equal((same * 255).round().astype(np.uint8), before)
    with pytest.raises(ValueError, match="re-paint needs"):
        edit_texture(before, 1, "handle", prompt="gold")
    edit_group(st, "handle", hue=-40, saturation=1.5, value=0.8)
    assert st.read_bytes("template/group_1_handle.png") == encode_png(tex)
    from proctex.serve.service import GroupEdit

    assert svc.edited_texture(1, GroupEdit(-40, 1.5, 0.8))[1] == encode_png(tex)


def test_linked_answers_carry_geometry_only_and_the_textures_are_cached_by_digest(client, root, tmp_path):
    """``?textures=linked``: the same geometry and UVs as the self-contained answer, images by
    relative URI (resolved against the transfer URL, they give the embedded PNGs byte for byte) and
    far fewer bytes; the texture route answers with an ETag (304 on a match) and is immutable for
    the digest the GLB names. A per-request edit embeds the edited texture; a stored edit changes
    the URI."""
    import posixpath
    import shutil
    from urllib.parse import urlsplit

    import pygltflib

    c, _ = client
    body = {"params": {"radius": 0.045}}
    full = c.post("/v1/families/mug/transfer", json=body)
    linked = c.post("/v1/families/mug/transfer?textures=linked", json=body)
    assert full.status_code == linked.status_code == 200
    geometry_full, images_full = _glb_parts(full.content)
    g = pygltflib.GLTF2().load_from_bytes(linked.content)
    blob = g.binary_blob()
    views = [g.accessors[a].bufferView for p in g.meshes[0].primitives for a in (p.attributes.POSITION, p.attributes.TEXCOORD_0, p.indices)]
    assert [blob[(g.bufferViews[i].byteOffset or 0) : (g.bufferViews[i].byteOffset or 0) + g.bufferViews[i].byteLength] for i in views] == geometry_full
    assert all(im.bufferView is None and im.uri.startswith("textures/") for im in g.images)
    assert len(linked.content) < len(full.content) - sum(len(v) for v in images_full.values()) + 4096
    for im in g.images:
        url = posixpath.join(posixpath.dirname("/v1/families/mug/transfer"), im.uri)
        answer = c.get(url)
        assert answer.status_code == 200 and answer.content == images_full[im.name]
        assert answer.headers["cache-control"].startswith("public") and "immutable" in answer.headers["cache-control"]
        again = c.get(urlsplit(url).path, headers={"If-None-Match": answer.headers["etag"]})
        assert again.status_code == 304 and again.content == b"" and again.headers["cache-control"] == "no-cache"
    edited = c.post("/v1/families/mug/transfer?textures=linked", json={**body, "edits": {"0": {"hue": 90}}})
    ge = pygltflib.GLTF2().load_from_bytes(edited.content)
    assert [im.uri is None for im in ge.images] == [True] + [False] * (len(ge.images) - 1)
    assert c.post("/v1/families/mug/transfer?textures=inline", json=body).status_code == 422
    assert c.get("/v1/families/mug/textures/9.png").status_code == 404
    assert c.get("/v1/families/mug/textures/0.jpg").status_code == 404
    # a stored edit: a new digest, so a new URI; the old one is no longer immutable
    shutil.copytree(root / "mug", tmp_path / "mug")
    cat = Catalog(str(tmp_path), check_every=0)
    c2 = TestClient(create_app(lambda: cat, edit_token="secret-token"))
    before = pygltflib.GLTF2().load_from_bytes(c2.post("/v1/families/mug/transfer?textures=linked", json=body).content).images[0].uri
    assert c2.post("/v1/families/mug/edits", json={"group": 0, "hue": 30}, headers={"X-ProcTex-Token": "secret-token"}).status_code == 200
    after = pygltflib.GLTF2().load_from_bytes(c2.post("/v1/families/mug/transfer?textures=linked", json=body).content).images[0].uri
    assert before != after
    assert c2.get("/v1/families/mug/" + before).headers["cache-control"] == "no-cache"


def test_stored_images_pickle_without_their_lock_and_decode_alike(root):
    """The template's lazily decoded images travel to other processes (a Ray task's argument) as
    their bytes and decode there to the same pixels."""
    import pickle

    svc = FamilyService(FamilyStore(root / "mug"))
    textures = svc.assets.textures
    back = pickle.loads(pickle.dumps(textures))
    assert back.png == textures.png and np.array_equal(back[0], textures[0])


@pytest.mark.parametrize(
    "path, message",
    [
        ("/v1/families/%2e%2e%2f", "no route"),  # was a 307 to /v1/families/.. with an empty body
        ("/v1/families/..%2f", "no route"),
        ("/v1/families/mug/", "no route"),
        ("/v1/families/mug/textures/0.normal.orm.png", "unknown group '0.normal'"),  # served the normal map
        ("/v1/families/mug/textures/0.orm.orm.png", "unknown group '0.orm'"),
    ],
)
def test_odd_paths_answer_a_json_404_not_a_redirect_or_another_file(client, path, message):
    c, _ = client
    r = c.get(path, follow_redirects=False)
    assert r.status_code == 404 and message in r.json()["error"], (r.status_code, r.text[:200])
    assert c.get("/v1/families/mug/textures/0.png").status_code == 200
