"""Hostile but legitimate input (issue 18): bounded work per request, every error a JSON answer, no
memory blow-up from coincident vertices, budgets that stop work between steps."""

from __future__ import annotations

import io
import json
import struct
import threading

import numpy as np
import pytest

from proctex.geometry.meshio import load_mesh_bytes, obj_text, position_ids
from proctex.models import get_model
from proctex.serve.catalog import Catalog, Watchdog
from proctex.serve.service import Limits
from proctex.store.config import BuildConfig
from proctex.store.layout import FamilyStore
from proctex.transfer.assets import load_assets
from proctex.transfer.budget import Budget, OverBudget

fastapi = pytest.importorskip("fastapi")
from fastapi.testclient import TestClient  # noqa: E402

from workers.http import create_app  # noqa: E402


@pytest.fixture(scope="module")
def root(painted_mug_root):
    return painted_mug_root


def _client(root, **limits):
    cat = Catalog(str(root), Limits(**{"max_bytes": 2_000_000, **limits}), check_every=0)
    return TestClient(create_app(lambda: cat)), cat


def _triangle_copies(n: int, spread: float = 0.2, seed: int = 0) -> bytes:
    """An OBJ of ``n`` copies of one small triangle scattered around the mug."""
    rng = np.random.default_rng(seed)
    tri = np.array([[0.0, 0.0, 0.0], [0.004, 0.0, 0.0], [0.0, 0.004, 0.002]])
    verts = np.concatenate([tri + rng.uniform(-spread, spread, 3) for _ in range(n)])
    faces = np.arange(3 * n).reshape(n, 3)
    return obj_text(verts, faces).encode()


def _distinct_boxes(n: int, seed: int = 0) -> bytes:
    """The mug plus ``n`` boxes of different proportions beside it: parts the template has no slot
    for, each unlike the others (no shortcut: each is matched on its own)."""
    from proctex.geometry.primitives import box

    rng = np.random.default_rng(seed)
    mug = get_model("mug").generate()
    verts, faces, off = [mug.vertices], [mug.faces], mug.n_vertices
    for _ in range(n):
        b = box(rng.uniform(0.005, 0.03, 3))
        v = b.vertices + rng.uniform(-0.15, 0.15, 3)
        verts.append(v)
        faces.append(b.faces + off)
        off += len(v)
    return obj_text(np.concatenate(verts), np.concatenate(faces)).encode()


# ------------------------------------------------------------------------------------------ meshes
def test_weld_ids_equal_a_brute_force_reference_and_coincident_clusters_cost_linear_memory():
    rng = np.random.default_rng(3)
    pts = rng.uniform(0, 1, (300, 3))
    pts = np.concatenate([pts, pts[:50], pts[:20] + 1e-9, rng.uniform(0, 1, (30, 3))])
    tol = 0.02
    ids = position_ids(pts, tol)
    d = np.linalg.norm(pts[:, None] - pts[None], axis=2) <= tol  # brute force: transitive closure of "within tol"
    from scipy.sparse.csgraph import connected_components

    _, ref = connected_components(d, directed=False)
    same = ids[:, None] == ids[None]
    assert np.array_equal(same, ref[:, None] == ref[None])
    # 12,000 vertices at three positions (an STL soup of one triangle 4,000 times) weld to three.
    many = np.repeat(np.eye(3) * 1e-7, 4000, axis=0)
    assert len(np.unique(position_ids(many, 1e-6))) == 1
    # Thousands of distinct vertices crammed within the tolerance: refused, not listed pair by pair.
    cloud = rng.uniform(0, 1e-7, (5000, 3))
    with pytest.raises(ValueError, match="too many coincident vertices"):
        position_ids(cloud, 1e-6)


def test_an_stl_of_one_triangle_four_thousand_times_loads_in_linear_memory():
    tri = np.array([[0, 0, 0], [1e-7, 0, 0], [0, 1e-7, 0]], dtype=np.float32)
    stl = b"\0" * 80 + struct.pack("<I", 4000) + b"".join(struct.pack("<12fH", 0, 0, 1, *tri.reshape(-1), 0) for _ in range(4000))
    try:
        shape, _ = load_mesh_bytes(stl, "soup.stl")
        assert shape.n_faces <= 4000
    except ValueError as exc:  # degenerate after welding is a clear refusal too
        assert "faces" in str(exc) or "coincident" in str(exc)


# ------------------------------------------------------------------------------------------ budgets
def test_a_budget_stops_between_steps_and_a_cancel_names_itself():
    b = Budget(seconds=None)
    b.check("nothing")
    b.cancel()
    with pytest.raises(OverBudget, match="cancelled while mapping") as info:
        b.check("mapping")
    assert info.value.cancelled
    over = Budget(seconds=1e-9)
    with pytest.raises(OverBudget, match="time budget") as info:
        over.check("matching")
    assert not info.value.cancelled
    with pytest.raises(ValueError):
        Budget(seconds=0)


def test_transfer_checks_its_budget_and_identical_extra_parts_are_fitted_once(root, monkeypatch):
    import proctex.transfer.assign as assign
    from proctex.transfer.apply import transfer
    from proctex.transfer.mappers import IdentityMapper

    assets = load_assets(FamilyStore(root / "mug"))
    mug = get_model("mug").generate()
    odd = np.array([[0, 0, 0], [0.02, 0, 0], [0, 0.03, 0], [0, 0, 0.01]], dtype=float)  # a small tetrahedron
    tf = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    verts, faces = [mug.vertices], [mug.faces]
    for k in range(6):  # six translated copies
        faces.append(tf + sum(len(v) for v in verts))
        verts.append(odd + [0.2 + 0.05 * k, 0.0, 0.0])
    from proctex.geometry.shape import Shape

    shape = Shape(np.concatenate(verts), np.concatenate(faces))
    calls = []
    real = assign.match_extra
    monkeypatch.setattr(assign, "match_extra", lambda u, f, *a, **k: calls.append(len(f)) or real(u, f, *a, **k))
    result = transfer(shape, assets, IdentityMapper())
    assert calls.count(4) <= 1  # six copies of the tetrahedron, one fit (or none when a cheaper test placed them)
    assert len([a for a in result.assignment if a.part >= 2]) == 6
    cancelled = Budget()
    cancelled.cancel()
    with pytest.raises(OverBudget):
        transfer(shape, assets, IdentityMapper(), budget=cancelled)


# ------------------------------------------------------------------------------------------- HTTP
def test_four_thousand_tiny_parts_are_refused_before_any_matching(root):
    c, _ = _client(root)
    r = c.post("/v1/families/mug/transfer", files={"mesh": ("many.obj", _triangle_copies(4000))})
    assert r.status_code == 422 and "4000 parts" in r.json()["error"]


def test_a_transfer_past_its_budget_is_a_422_and_the_other_routes_answer_meanwhile(root):
    c, cat = _client(root, max_seconds=15.0)  # long enough that the other requests surely come first
    body = _distinct_boxes(120)
    order: list[str] = []
    answers: dict[str, int] = {}

    def slow():
        r = c.post("/v1/families/mug/transfer", files={"mesh": ("boxes.obj", body)})
        answers["transfer"] = r.status_code
        answers["transfer_error"] = r.json().get("error", "") if r.status_code != 200 else ""
        order.append("transfer")

    t = threading.Thread(target=slow)
    t.start()
    for _ in range(200):  # wait until the transfer is under way
        if c.get("/healthz").json()["transfers_running"]:
            break
        threading.Event().wait(0.02)
    for route in ("/healthz", "/v1/families", "/v1/families/mug", "/v1/families/mug/groups/0/texture.png?size=16"):
        r = c.get(route)
        answers[route] = r.status_code
        order.append(route)
    t.join(timeout=120)
    assert not t.is_alive()
    assert all(answers[r] == 200 for r in ("/healthz", "/v1/families", "/v1/families/mug", "/v1/families/mug/groups/0/texture.png?size=16"))
    if answers["transfer"] == 422:  # the budget stopped it: the other routes were answered first
        assert "time budget" in answers["transfer_error"]
        assert order.index("transfer") == len(order) - 1
    else:  # a fast machine finished within the budget
        assert answers["transfer"] == 200


@pytest.mark.parametrize(
    "method, path, kwargs, status",
    [
        ("post", "/v1/families/mug/transfer", {"json": {"params": {"radius": int("9" * 400)}}}, 422),
        ("post", "/v1/families/mug/transfer", {"json": {"params": {}, "seed": int("9" * 400)}}, 422),
        ("post", "/v1/families/mug/transfer", {"content": b'{"params": ' + b"[" * 3000 + b"]" * 3000 + b"}", "headers": {"content-type": "application/json"}}, 422),
        ("post", "/v1/families/mug/transfer", {"files": {"mesh": ("m.obj", b"v 0 0 0\n")}, "data": {"seed": "9" * 400}}, 422),
        ("post", "/v1/families/mug/transfer", {"files": {"mesh": ("m.obj", b"v 0 0 0\n")}, "data": {"edits": "[" * 5000}}, 422),
        ("get", "/v1/families/mug/groups/0/texture.png?hue=" + "9" * 400, {}, 422),
        ("get", "/v1/families/mug/groups/0/texture.png?size=" + "9" * 400, {}, 422),
        ("get", "/v1/families/" + "a" * 1500, {}, 404),
        ("get", "/v1/families/a%5Cb", {}, 404),
        ("get", "/v1/families/a%00b", {}, 404),
        ("post", "/v1/families/" + "x" * 2000 + "/transfer", {"json": {"params": {}}}, 404),
        ("post", "/v1/families/mug/edits", {"content": b"[" * 5000, "headers": {"content-type": "application/json"}}, 403),  # read-only
    ],
)
def test_hostile_requests_get_json_errors_not_tracebacks(root, method, path, kwargs, status):
    c, _ = _client(root)
    r = getattr(c, method)(path, **kwargs)
    assert r.status_code == status, r.text[:300]
    assert r.headers["content-type"].startswith("application/json") and "error" in r.json()


def test_a_body_without_content_length_is_cut_off_at_the_limit(root):
    c, _ = _client(root, max_bytes=10_000)

    def chunks():
        for _ in range(100):
            yield b"x" * 1000

    r = c.post("/v1/families/mug/transfer", content=chunks(), headers={"content-type": "application/json"})
    assert r.status_code == 413 and "limit" in r.json()["error"]


def test_an_unexpected_error_is_a_json_500_naming_its_type(root, monkeypatch):
    c, cat = _client(root)
    svc = cat.get("mug")
    monkeypatch.setattr(svc, "describe", lambda: {}["missing"])
    r = c.get("/v1/families/mug")
    assert r.status_code == 500 and r.json()["error"].startswith("internal error (KeyError)")


def test_a_stuck_transfer_turns_healthz_to_503(root):
    dog = Watchdog(stuck_after=0.0)
    cat = Catalog(str(root), Limits(), check_every=0)
    c = TestClient(create_app(lambda: cat, watchdog=dog))
    assert c.get("/healthz").json()["status"] == "ok"
    token = dog.begin()
    threading.Event().wait(0.01)
    r = c.get("/healthz")
    assert r.status_code == 503 and r.json()["status"] == "stuck" and r.json()["transfers_running"] == 1
    dog.end(token)
    assert c.get("/healthz").status_code == 200


def test_limits_refuse_nonsense():
    for bad in ({"max_parts": 0}, {"max_seconds": float("nan")}, {"max_bytes": -1}, {"max_faces": True}):
        with pytest.raises(ValueError):
            Limits(**bad)
    assert json.dumps(Limits().__dict__)
    assert io


# -------------------------------------------------------------------------------------------- CLI
def _cli(argv, capsys):
    from proctex.cli import main

    code = main(argv)
    err = capsys.readouterr().err
    return code, err


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--params", "[" * 5000 + "]" * 5000], "error:"),
        (["--params", '{"radius": ' + "9" * 400 + "}"], "error:"),
        (["--params", '{"radius": 1e999}'], "error:"),
        (["--mesh", "/nonexistent/x.obj"], "error:"),
    ],
)
def test_cli_transfer_bad_input_is_an_error_line_and_writes_nothing(root, tmp_path, capsys, extra, message):
    out = tmp_path / "x.glb"
    code, err = _cli(["transfer", str(root / "mug"), *extra, "--out", str(out)], capsys)
    assert code == 2 and err.startswith(message) and "Traceback" not in err
    assert not out.exists() and not list(tmp_path.glob(".*tmp"))


def test_cli_outputs_are_checked_before_any_work(root, tmp_path, capsys):
    fam = str(root / "mug")
    out = tmp_path / "x.glb"
    out.write_bytes(b"keep me")
    code, err = _cli(["transfer", fam, "--params", "{}", "--out", str(out)], capsys)
    assert code == 2 and "--force" in err and out.read_bytes() == b"keep me"
    code, err = _cli(["transfer", fam, "--params", "{}", "--out", str(out), "--force"], capsys)
    assert code == 0 and out.read_bytes()[:4] == b"glTF"
    (tmp_path / "dir.glb").mkdir()
    for bad in (str(tmp_path / "dir.glb"), "/proc/nope/x.glb", str(out / "under_a_file.glb")):
        code, err = _cli(["transfer", fam, "--params", "{}", "--out", bad], capsys)
        assert code == 2 and err.startswith("error:"), (bad, err)
    assert not [p for p in tmp_path.rglob("*") if p.name.endswith(".tmp")]
    code, err = _cli(["segment", "mug", "--tol", "nan"], capsys)
    assert code == 2 and "--tol" in err


def test_a_config_with_a_nan_seed_is_refused_before_the_store_is_touched(tmp_path, capsys):
    cfg = tmp_path / "bad.json"
    cfg.write_text('{"model": "mug", "seed": NaN}')
    code, err = _cli(["build", str(cfg), "--out", str(tmp_path / "fam")], capsys)
    assert code == 2 and "seed" in err
    assert not (tmp_path / "fam" / "family.json").exists()
    for bad in ({"model": "mug", "n_train": 2.5}, {"model": "mug", "seed": -1}, {"model": "mug", "paint": {"texture_size": 1e9}}):
        with pytest.raises(ValueError):
            BuildConfig.from_dict(bad)


# ------------------------------------------------------------------------------------------ edits
EDITOR = """
import sys
from proctex.serve.catalog import Catalog
cat = Catalog(sys.argv[1], check_every=0)
for k in range(int(sys.argv[2])):
    svc = cat.get("mug")
    svc.persist_edit({"group": k % 2, "hue": 7})
"""


def test_concurrent_edits_from_two_processes_apply_in_order_and_lose_nothing(root, tmp_path):
    """Two processes (two replicas) store ten edits each at once: twenty versions, and every edit
    starts from the texture the one before it left (the before / after digests form one chain)."""
    import shutil
    import subprocess
    import sys

    shutil.copytree(root / "mug", tmp_path / "mug")
    procs = [subprocess.Popen([sys.executable, "-c", EDITOR, str(tmp_path), "10"], stderr=subprocess.PIPE) for _ in range(2)]
    for p in procs:
        _, err = p.communicate(timeout=600)
        assert p.returncode == 0, err.decode()[-2000:]
    st = FamilyStore(tmp_path / "mug")
    edits = st.read_json("template/paint.json")["edits"]
    assert [e["version"] for e in edits] == list(range(1, 21))
    for g in (0, 1):
        chain = [e for e in edits if e["group"] == g]
        assert len(chain) == 10
        assert all(a["after"] == b["before"] for a, b in zip(chain, chain[1:]))  # no edit overwrote another
    from proctex.store.layout import StoreLayout, digest

    labels = {g["group"]: g["label"] for g in st.read_json("template/paint.json")["groups"]}
    for g in (0, 1):
        last = [e for e in edits if e["group"] == g][-1]
        assert digest(st.read_bytes(StoreLayout.texture(g, labels[g]))) == last["after"]


# ----------------------------------------------------------------------------------------- damage
def _damage(folder, how):
    from proctex.store.layout import StoreLayout

    st = FamilyStore(folder)
    summary = st.read_json("template/paint.json")
    g = summary["groups"][0]
    png = folder / StoreLayout.texture(g["group"], g["label"])
    if how == "truncated png":
        png.write_bytes(png.read_bytes()[: len(png.read_bytes()) // 2])
    elif how == "greyscale png":
        from PIL import Image

        Image.open(png).convert("L").save(png)
    elif how == "wrong size png":
        from PIL import Image

        Image.open(png).resize((8, 8)).save(png)
    elif how == "changed png":
        from PIL import Image

        img = np.asarray(Image.open(png).convert("RGB")).copy()
        img[0, 0] = 255 - img[0, 0]
        Image.fromarray(img).save(png)
    elif how == "damaged family.json":
        (folder / "family.json").write_text('{"config": ')
    elif how == "missing uv":
        (folder / "template" / "uv.npz").unlink()
    elif how == "truncated uv":
        p = folder / "template" / "uv.npz"
        p.write_bytes(p.read_bytes()[:100])
    elif how == "truncated painted masks":
        p = folder / "template" / "painted.npz"
        p.write_bytes(p.read_bytes()[:50])
    elif how == "damaged paint.json":
        (folder / "template" / "paint.json").write_text("[1, 2")
    elif how == "paint.json without groups":
        summary["groups"] = summary["groups"][:1]
        st.write_json("template/paint.json", summary)
    elif how == "missing texture":
        png.unlink()
    elif how == "png that is a jpeg":
        from PIL import Image

        Image.open(png).convert("RGB").save(png, format="JPEG")
    elif how == "wrong uv shape":
        st.write_arrays("template/uv.npz", corner_uv=np.zeros((3, 3, 2)), face_group=np.zeros(3, np.int64))
    elif how == "garbage model":
        (folder / "models").mkdir(exist_ok=True)
        (folder / "models" / "group_0.pt").write_bytes(b"\x80\x04garbage")
    elif how == "family.json of another shape":
        (folder / "family.json").write_text('{"config": {"source": {"model": "nosuch"}}, "stages": {"paint": {"state": "done"}}}')


@pytest.mark.parametrize(
    "how",
    [
        "truncated png",
        "greyscale png",
        "wrong size png",
        "changed png",
        "damaged family.json",
        "missing uv",
        "truncated uv",
        "truncated painted masks",
        "damaged paint.json",
        "paint.json without groups",
        "missing texture",
        "png that is a jpeg",
        "wrong uv shape",
        "garbage model",
        "family.json of another shape",
    ],
)
def test_a_damaged_family_is_unavailable_and_the_others_are_served(root, tmp_path, how):
    import shutil

    for name in ("good", "bad"):
        shutil.copytree(root / "mug", tmp_path / name)
    _damage(tmp_path / "bad", how)
    cat = Catalog(str(tmp_path), check_every=0)
    c = TestClient(create_app(lambda: cat))
    assert c.post("/v1/families/good/transfer", json={"params": {}}).status_code == 200
    r = c.post("/v1/families/bad/transfer", json={"params": {}})
    assert r.status_code == 503 and "bad" in r.json()["error"], r.text
    health = c.get("/v1/families").json()["health"]
    assert health["good"] == "ok" and "unavailable" in health["bad"]
    h = c.get("/healthz").json()
    assert h["status"] == "ok" and h["unavailable"] == ["bad"]
    assert c.get("/v1/families/bad").status_code == 503


def test_a_swapped_or_altered_network_is_refused_on_load(tmp_path):
    from proctex.build.pipeline import build
    from proctex.store.networks import load_models

    cfg = BuildConfig.from_dict(
        dict(model="mug", n_train=2, n_test=0, corr_points=200, cage_iterations=5, texture_size=32, train={"iterations": 5, "eval_every": 5, "context_points": 64, "query_points": 32})
    )
    st = FamilyStore(tmp_path / "mug")
    build(st, cfg, stages=("sample", "template", "paint", "pairs", "train"), log=lambda *_: None)
    assert sorted(load_models(st)) == [0, 1]
    models = tmp_path / "mug" / "models"
    a, b = (models / "group_0.pt").read_bytes(), (models / "group_1.pt").read_bytes()
    (models / "group_0.pt").write_bytes(b)
    (models / "group_1.pt").write_bytes(a)
    with pytest.raises(ValueError, match="checksum mismatch|holds the network of group"):
        load_models(st)
    state = st.read_json("family.json")
    for g in state["stages"]["train"]["groups"].values():
        g.pop("sha256")  # an older store: no checksums, the group inside the file still tells
    st.write_json("family.json", state)
    with pytest.raises(ValueError, match="holds the network of group 1"):
        load_models(st)


def test_a_gltf_upload_that_refers_to_files_is_refused(root):
    c, _ = _client(root)
    for uri in ("/etc/passwd", "../../family.json", "http://example.com/x.bin"):
        doc = {"asset": {"version": "2.0"}, "buffers": [{"uri": uri, "byteLength": 12}]}
        r = c.post("/v1/families/mug/transfer", files={"mesh": ("m.gltf", json.dumps(doc).encode())})
        assert r.status_code == 422 and "self-contained" in r.json()["error"]
