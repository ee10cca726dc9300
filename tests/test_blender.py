""".blend files as family sources (issue 19, first slice): a Geometry Nodes model built in code,
saved, and used as a black box through its own Blender process. Skipped with the reason where no
Python with ``bpy`` exists (``make blender`` makes ``.venv-blender``)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest

from proctex.geometry.parts import segment
from proctex.sources.blender import BlenderModel, blender_python, input_specs

from .processes import free_port

PYTHON = blender_python()
needs_bpy = pytest.mark.skipif(PYTHON is None, reason="no Python with bpy (make blender makes .venv-blender; bpy not installable here?)")

FIXTURES = Path(__file__).parent / "fixtures" / "blend" / "make_fixtures.py"


@pytest.fixture(scope="module")
def blends(tmp_path_factory):
    """The fixture files (``vase.blend``, ``table.blend``), built in code by ``make_fixtures.py``."""
    if PYTHON is None:
        pytest.skip("no Python with bpy")
    out = tmp_path_factory.mktemp("blend")
    done = subprocess.run([PYTHON, str(FIXTURES), str(out)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and (out / "table.blend").exists(), done.stderr[-2000:]
    return out


@pytest.fixture(scope="module")
def vase_blend(blends):
    return blends / "vase.blend"


@needs_bpy
def test_the_modifier_inputs_are_the_parameter_space(vase_blend):
    model = BlenderModel(vase_blend, "Vase")
    try:
        specs = {s.name: s for s in model.space.specs}
        assert set(specs) == {"Height", "Resolution", "Capped"}
        assert (specs["Height"].kind, specs["Height"].low, specs["Height"].high, specs["Height"].default) == ("continuous", 0.2, 3.0, 1.0)
        assert (specs["Resolution"].kind, specs["Resolution"].low, specs["Resolution"].high) == ("integer", 3, 64)
        assert specs["Capped"].kind == "choice" and specs["Capped"].options == (False, True)
    finally:
        model.close()


@needs_bpy
def test_generation_is_deterministic_and_the_topology_follows_the_inputs(vase_blend):
    model = BlenderModel(vase_blend, "Vase", bounds={"Resolution": [4, 40]}, pins={"Capped": True})
    try:
        assert [s.name for s in model.space.specs] == ["Height", "Resolution"]
        a = model.generate({"Height": 1.5, "Resolution": 8})
        b = model.generate({"Height": 1.5, "Resolution": 8})
        assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
        assert np.isclose(np.ptp(a.vertices[:, 2]), 1.5)  # the depth follows "Height"
        c = model.generate({"Height": 1.5, "Resolution": 32})
        assert c.n_vertices == 4 * a.n_vertices and c.n_faces > a.n_faces  # the ring follows "Resolution"
        assert segment(c).n_parts == 1 and model.last_seconds >= 0
        with pytest.raises(ValueError):
            model.generate({"Resolution": 64})  # outside the narrowed bounds
    finally:
        model.close()


@needs_bpy
def test_bad_files_objects_and_modifiers_are_clear_errors(vase_blend, tmp_path):
    with pytest.raises(ValueError, match="no such .blend"):
        BlenderModel(tmp_path / "missing.blend", "Vase")
    with pytest.raises(ValueError, match="no object 'Table'"):
        BlenderModel(vase_blend, "Table")
    with pytest.raises(ValueError, match="no Geometry Nodes modifier 'Other'"):
        BlenderModel(vase_blend, "Vase", modifier="Other")
    with pytest.raises(ValueError, match="must lie within"):
        BlenderModel(vase_blend, "Vase", bounds={"Height": [0.0, 9.0]})


def test_inputs_default_to_the_files_values_and_unranged_or_unlisted_ones_are_held_there():
    """The modifier's values are the defaults; an input without a usable range, or one a spec does
    not list, is held at the file's value (a one-value parameter, never refused); a build in which
    nothing varies is refused, naming what could vary; a file value outside the spec's range is
    clamped into it and reported."""
    big = {"min": -3.4e38, "max": 3.4e38}
    inputs = [
        {"name": "Size", "identifier": "S1", "type": "float", "default": 0.0, "value": 0.3, **big},
        {"name": "Count", "identifier": "S2", "type": "int", "default": 0, "value": 4, "min": 1, "max": 9},
        {"name": "Has Back", "identifier": "S3", "type": "bool", "default": False, "value": True},
        {"name": "Style", "identifier": "S4", "type": "menu", "default": "B", "value": "B", "options": ["A", "B"]},
    ]
    plan = input_specs(inputs)  # no list: Count, Has Back and Style vary; Size has no range
    assert plan.fixed == {"Size": 0.3} and "no usable range" in plan.why["Size"]
    space = plan.space
    assert (space["Size"].low, space["Size"].high, space["Size"].default) == (0.3, 0.3, 0.3)
    assert (space["Count"].low, space["Count"].high, space["Count"].default) == (1, 9, 4)
    assert space["Has Back"].options == (False, True) and space["Has Back"].default is True and space["Style"].default == "B"
    assert all(p["Size"] == 0.3 for p in space.sample(5, seed=0))  # held, in every sample
    listed = input_specs(inputs, bounds={"Size": [0.5, 2.0]}, listed=["Has Back"])  # a spec listing Size (bounded) and Has Back
    assert set(listed.fixed) == {"Count", "Style"} and listed.why["Count"] == "the spec does not list it"
    assert listed.space["Style"].options == ("B",) and listed.space["Count"].low == listed.space["Count"].high == 4
    assert listed.clamped == {"Size": (0.3, 0.5, 2.0)} and listed.space["Size"].default == 0.5
    assert any("clamped to 0.5" in n for n in listed.notes()) and any("'Count' held at the file's value" in n for n in listed.notes())
    with pytest.raises(ValueError, match=r"no input varies .*'Size'.*params spec"):
        input_specs(inputs[:1])
    with pytest.raises(ValueError, match=r"no input varies .*'Count'"):
        input_specs(inputs, listed=[])
    with pytest.raises(ValueError, match="no input 'Nope'"):
        input_specs(inputs, pins={"Nope": 1})


@needs_bpy
def test_a_table_with_a_menu_and_a_leg_count_changes_its_parts(blends):
    """The menu's options come from the modifier; every leg is one more part; the menu switches the
    top's mesh."""
    model = BlenderModel(blends / "table.blend", "Table")
    try:
        specs = {s.name: s for s in model.space.specs}
        assert specs["Top Shape"].kind == "choice" and specs["Top Shape"].options == ("Round", "Square")
        assert specs["Top Shape"].default == "Round"
        assert (specs["Legs"].low, specs["Legs"].high, specs["Legs"].default) == (3, 8, 4)
        for legs in (3, 5, 8):
            assert segment(model.generate({"Legs": legs})).n_parts == 1 + legs
        round_top, square_top = (model.generate({"Legs": 3, "Top Shape": t}) for t in ("Round", "Square"))
        assert square_top.n_faces < round_top.n_faces  # a box against a 32-sided disc
        assert np.allclose(np.ptp(square_top.vertices[:, :2], axis=0), 1.2)
        assert np.allclose(square_top.vertices[:, :2].min(axis=0), -0.6) and np.isclose(square_top.vertices[:, 2].min(), 0.0)  # its own frame
        with pytest.raises(ValueError, match="Top Shape"):
            model.generate({"Top Shape": "Oval"})
    finally:
        model.close()


@needs_bpy
def test_a_part_attribute_overrides_connectivity_and_a_uv_map_travels_with_the_shape(vase_blend):
    """The vase is one connected mesh; its ``part_id`` face attribute cuts it in two, at the middle.
    Its ``UVMap`` comes back per face corner, equal to the cylinder's own layout."""
    plain = BlenderModel(vase_blend, "Vase")
    model = BlenderModel(vase_blend, "Vase", parts="part_id", uv="UVMap")
    try:
        one = plain.generate({"Resolution": 10})
        two = model.generate({"Resolution": 10})
        assert segment(one).n_parts == 1 and one.corner_uv is None
        seg = segment(two)
        assert seg.n_parts == 2 and two.n_faces == one.n_faces and two.n_vertices == one.n_vertices + 10  # the middle ring, twice
        centres = two.vertices[two.faces].mean(axis=1)[:, 2]
        for p in range(2):  # each part lies on one side of the middle
            side = centres[seg.face_part == p]
            assert (side > 0).all() or (side < 0).all()
        assert ("UVMap", "CORNER", "FLOAT2") in model.attributes and ("part_id", "FACE", "INT") in model.attributes
        assert two.corner_uv.shape == (two.n_faces, 3, 2) and 0 <= two.corner_uv.min() and two.corner_uv.max() <= 1
        assert np.ptp(two.corner_uv[..., 0]) > 0.9  # the side's strip spans the whole width
        with pytest.raises(ValueError, match="no attribute 'nope'.*part_id"):
            BlenderModel(vase_blend, "Vase", parts="nope").generate({})
        with pytest.raises(ValueError, match="not a UV map"):
            BlenderModel(vase_blend, "Vase", uv="part_id").generate({})
    finally:
        plain.close()
        model.close()


FAKE_BLENDER = """#!{python}
import json, os, signal, sys
for line in sys.stdin:
    req = json.loads(line)
    if req["op"] == "open":
        print(json.dumps({{"inputs": [{{"name": "Size", "identifier": "S", "type": "float", "default": 1.0, "min": 0.0, "max": 2.0}}]}}), flush=True)
    elif req["op"] == "generate" and req["params"].get("Size", 1.0) > 1.5:
        os.kill(os.getpid(), signal.SIGSEGV)  # what a crashing evaluation looks like from outside
    elif req["op"] == "generate":
        import time; time.sleep(float(req["params"].get("Size", 1.0)) * 10)
"""


def test_a_blender_process_that_crashes_or_hangs_is_an_error_and_the_next_request_starts_a_new_one(tmp_path):
    """A stand-in for Blender (a process speaking the protocol) segfaults on one input and hangs on
    another: both are ``ValueError``s naming what happened, the caller lives on, and the next request
    opens the file in a fresh process."""
    import sys

    from proctex.sources.blender import BlenderSession

    fake = tmp_path / "fake_python"
    fake.write_text(FAKE_BLENDER.format(python=sys.executable))
    fake.chmod(0o755)
    blend = tmp_path / "x.blend"
    blend.write_bytes(b"BLENDER")
    session = BlenderSession(blend, "Thing", python=str(fake), timeout=2.0)
    try:
        first = session.proc.pid
        with pytest.raises(ValueError, match=r"ended \(signal 11\) during 'generate'"):
            session.generate({"Size": 1.8})
        with pytest.raises(ValueError, match="did not answer 'generate' within 2 s"):
            session.generate({"Size": 1.0})
        assert session.restarts == 1 and session.proc.pid != first and session.proc.poll() is not None  # the hung one was stopped
        with pytest.raises(ValueError, match="signal 11"):
            session.generate({"Size": 1.9})
        assert session.restarts == 2
    finally:
        session.close()


@needs_bpy
def test_a_killed_blender_process_is_replaced_and_gives_the_same_shapes(vase_blend):
    model = BlenderModel(vase_blend, "Vase")
    try:
        a = model.generate({"Resolution": 12})
        model.session.proc.kill()
        model.session.proc.wait()
        b = model.generate({"Resolution": 12})
        assert model.session.restarts == 1 and np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
    finally:
        model.close()


@needs_bpy
@pytest.mark.slow
def test_a_blend_family_builds_and_transfers_new_parameters(vase_blend, tmp_path, capsys):
    """``proctex build --blend`` samples the .blend through its Blender process, paints, solves
    pairs and trains; ``proctex transfer`` textures new parameters (a new ring count) into a GLB."""
    import json

    from proctex.cli import main
    from proctex.store.layout import FamilyStore
    from proctex.texture.gltf_read import read_textured_glb

    out = tmp_path / "fam"
    code = main(
        [
            "build",
            "--blend",
            str(vase_blend),
            "--object",
            "Vase",
            "--prompt",
            "blue ceramic",
            "--n-train",
            "3",
            "--n-test",
            "0",
            "--texture-size",
            "64",
            "--points",
            "200",
            "--iterations",
            "20",
            "--train-iterations",
            "20",
            "--out",
            str(out),
            "--quiet",
            "--stages",
            "sample,template,paint,pairs,train",
            "--parts-attribute",
            "part_id",
            "--keep-uv",
            "UVMap",
        ]
    )
    assert code == 0, capsys.readouterr().err
    store = FamilyStore(out)
    state = store.read_json("family.json")
    assert state["config"]["source"]["blender"] == {"file": str(vase_blend), "object": "Vase", "modifier": "GeometryNodes", "parts": "part_id", "uv": "UVMap"}
    # the graph's parts (two halves) and its UV map (kept for each group's representative)
    from proctex.store.template import load_template

    template = load_template(store)
    assert template.grouping.segmentation.n_parts == 2
    made = template.shape.corner_uv
    for g in template.grouping.groups:
        faces = template.grouping.parts[g.representative].faces
        assert np.allclose(template.corner_uv[faces], made[faces])
    assert all(state["stages"][s]["state"] == "done" for s in ("sample", "template", "paint", "pairs", "train"))
    # loading the family for serving starts no Blender: its space and template shape are records
    import proctex.sources.blender as blender
    import proctex.sources.registry as registry
    from proctex.serve.service import FamilyService

    def no_blender(*a, **k):
        raise AssertionError("Blender was started to load the family")

    with pytest.MonkeyPatch.context() as m:
        m.setattr(blender.BlenderSession, "__init__", no_blender)
        m.setattr(registry, "_OPEN", {})  # not even one this process already has open
        svc = FamilyService(store, "vase")
        described = svc.describe()
    assert {p["name"] for p in described["parameters"]} >= {"Height", "Resolution"} and described["parts_attribute"] == "part_id"
    assert svc.assets.grouping.segmentation.n_parts == 2
    glb = tmp_path / "v.glb"
    code = main(["transfer", str(out), "--params", json.dumps({"Height": 2.0, "Resolution": 24}), "--out", str(glb)])
    assert code == 0, capsys.readouterr().err
    mesh = read_textured_glb(glb.read_bytes())
    assert len(mesh.faces) > 0 and len(mesh.textures) >= 1


@needs_bpy
@pytest.mark.slow
@pytest.mark.ray
def test_a_blend_family_fans_out_on_ray_like_any_other_source(vase_blend, tmp_path):
    """Sampling and cage pairs of a .blend family as Ray tasks: each worker opens the file once in
    its own Blender process; the samples equal the single-process build's."""
    import ray

    from proctex.build.pipeline import build
    from proctex.store.config import BuildConfig
    from proctex.store.layout import FamilyStore
    from proctex.store.samples import samples
    from workflows.build import build_on_ray

    cfg = BuildConfig.from_dict(
        {
            "source": {"blender": {"file": str(vase_blend), "object": "Vase"}, "n_train": 4, "n_test": 0},
            "paint": {"prompt": "blue ceramic", "texture_size": 32},
            "corr_points": 200,
            "cage": {"iterations": 10},
        }
    )
    stages = ("sample", "template", "paint", "pairs")
    local = FamilyStore(tmp_path / "local")
    build(local, cfg, stages=stages, log=lambda *_: None)
    was_up = ray.is_initialized()
    try:
        state = build_on_ray(str(tmp_path / "ray"), cfg, stages=stages, num_cpus=2, log=lambda *_: None, quiet=True)
    finally:
        if not was_up:
            ray.shutdown()
    assert all(state["stages"][s]["state"] == "done" for s in stages)
    on_ray = FamilyStore(tmp_path / "ray")
    assert [(r["id"], r["faces"], r["params"]) for r in samples(on_ray)] == [(r["id"], r["faces"], r["params"]) for r in samples(local)]
    assert len({r["faces"] for r in samples(on_ray)}) > 1  # the ring count varies across the family


# ------------------------------------------------------------------------------- the Blender add-on
ADDON = Path(__file__).resolve().parents[1] / "clients" / "blender"
DRIVER = Path(__file__).parent / "fixtures" / "blend" / "drive_addon.py"
ADDON_TOKEN = "addon-test-token"  # the served vase's edit token: the add-on's photo looks need it


@pytest.fixture(scope="module")
def served_vase(blends, tmp_path_factory):
    """A vase family built from ``vase.blend`` and served by a real ``proctex serve`` (Ray Serve, one
    replica) on 127.0.0.1: ``(URL, family store)``. The server is this fixture's own process group."""
    from proctex.build.pipeline import build
    from proctex.store.config import BuildConfig
    from proctex.store.layout import FamilyStore

    root = tmp_path_factory.mktemp("served")
    cfg = BuildConfig.from_dict(
        {
            "source": {"blender": {"file": str(blends / "vase.blend"), "object": "Vase"}, "n_train": 3, "n_test": 0},
            "paint": {"prompt": "blue ceramic", "texture_size": 64},
            "corr_points": 200,
            "cage": {"iterations": 20},
            "train": {"iterations": 20},
        }
    )
    store = FamilyStore(root / "vase")
    build(store, cfg, stages=("sample", "template", "paint", "pairs", "train"), log=lambda *_: None)
    from dataclasses import replace

    from proctex.looks import add_look

    add_look(store, "red", replace(cfg.paint, prompt="red lacquer"), log=lambda *_: None)  # a second look for the add-on's picker
    from .processes import serving

    import os

    with serving(str(root), root / "serve.log", replicas=1, env={**os.environ, "PROCTEX_EDIT_TOKEN": ADDON_TOKEN}) as (url, proc):
        yield url, store
    assert proc.returncode == 0 and "stopping" in (root / "serve.log").read_text(), (root / "serve.log").read_text()[-2000:]


def test_the_addon_client_speaks_the_api_and_reports_errors_plainly():
    """The add-on's HTTP client (standard library only) without Blender: URLs checked, multipart
    bodies well formed, OBJ text exact, an unreachable service a ServiceError."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("proctex_addon_client", ADDON / "proctex_blender" / "client.py")
    client = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(client)
    assert client.obj_text([0, 0, 0, 1, 0, 0, 0, 1, 0.5], [0, 1, 2]) == b"v 0 0 0\nv 1 0 0\nv 0 1 0.5\nf 1 2 3\n"
    body, ctype = client.multipart({"seed": "3"}, "mesh", "mesh.obj", b"v 0 0 0\n")
    boundary = ctype.split("boundary=")[1]
    assert body.startswith(f"--{boundary}\r\n".encode()) and body.endswith(f"--{boundary}--\r\n".encode()) and b'name="seed"\r\n\r\n3' in body
    with pytest.raises(client.ServiceError, match="must look like"):
        client.families("ftp://x")
    with pytest.raises(client.ServiceError, match="cannot reach") as err:
        client.families(f"http://127.0.0.1:{free_port()}", timeout=2)
    assert err.value.status == 0
    with pytest.raises(client.ServiceError, match="pick a family"):
        client.transfer_params("http://127.0.0.1:1", "", {})
    assert client._transfer_path("mug", "red lacquer") == "/v1/families/mug/transfer?look=red%20lacquer"
    assert client._transfer_path("mug", None) == "/v1/families/mug/transfer"
    with pytest.raises(client.ServiceError, match="cannot reach"):
        client.looks(f"http://127.0.0.1:{free_port()}", "mug", timeout=2)
    # a photo look's multipart body (issue 53) reads back as the service reads it: the look's JSON and each file
    import asyncio
    import json

    from starlette.requests import Request

    body, ctype = client.multipart_files({"look": json.dumps({"name": "p"})}, [("image.*", 'odd"name\r\n.png', b"\x89PNG-bytes"), ("image.3", "b.jpg", b"\xff\xd8")])

    async def parse():
        async def receive():
            return {"type": "http.request", "body": body, "more_body": False}

        form = await Request({"type": "http", "method": "POST", "headers": [(b"content-type", ctype.encode())]}, receive).form()
        return {k: (v if isinstance(v, str) else (v.filename, await v.read())) for k, v in form.multi_items()}

    assert asyncio.run(parse()) == {"look": '{"name": "p"}', "image.*": ("oddname.png", b"\x89PNG-bytes"), "image.3": ("b.jpg", b"\xff\xd8")}
    with pytest.raises(client.ServiceError, match="edit token"):
        client.add_photo_look("http://127.0.0.1:1", "mug", "", "p", {"*": ("a.png", b"x")})
    with pytest.raises(client.ServiceError, match="at least one photo"):
        client.add_photo_look("http://127.0.0.1:1", "mug", "secret-token", "p", {})


def test_the_addon_zip_holds_the_package(tmp_path):
    import importlib.util
    import zipfile

    spec = importlib.util.spec_from_file_location("build_zip", ADDON / "build_zip.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    with zipfile.ZipFile(module.build(tmp_path / "a.zip")) as zf:
        names = set(zf.namelist())
    assert {"proctex_blender/__init__.py", "proctex_blender/client.py"} <= names and not any("__pycache__" in n for n in names)
    assert not any(n.endswith("blender_manifest.toml") for n in names)  # legacy: Blender reads bl_info


#: The manifest fields Blender's extension docs require (schema 1.0.0), and the ones it knows.
MANIFEST_REQUIRED = {"schema_version", "id", "version", "name", "tagline", "maintainer", "type", "blender_version_min", "license"}
MANIFEST_KNOWN = MANIFEST_REQUIRED | {"website", "tags", "blender_version_max", "copyright", "platforms", "wheels", "permissions", "build"}


def _manifest_problems(manifest: dict) -> list[str]:
    """What a manifest breaks of the documented rules (required fields, an id of lowercase letters,
    digits and underscores, semantic versions, a tagline of at most 64 characters not ending in
    punctuation, SPDX licences, permissions with a reason each)."""
    import re

    out = [f"missing {k}" for k in sorted(MANIFEST_REQUIRED - set(manifest))]
    out += [f"unknown {k}" for k in sorted(set(manifest) - MANIFEST_KNOWN)]
    if not re.fullmatch(r"[a-z][a-z0-9_]*", str(manifest.get("id", ""))):
        out.append("id")
    for key in ("version", "blender_version_min", "schema_version"):
        if not re.fullmatch(r"\d+\.\d+\.\d+", str(manifest.get(key, ""))):
            out.append(key)
    tag = str(manifest.get("tagline", ""))
    if not tag or len(tag) > 64 or not tag[-1].isalnum():
        out.append("tagline")
    if manifest.get("type") != "add-on":
        out.append("type")
    if not manifest.get("license") or not all(str(x).startswith("SPDX:") for x in manifest["license"]):
        out.append("license")
    perms = manifest.get("permissions", {})
    if not isinstance(perms, dict) or not all(k in ("files", "network", "clipboard", "camera", "microphone") and isinstance(v, str) and v for k, v in perms.items()):
        out.append("permissions")
    return out


def test_the_addon_is_a_blender_extension_with_a_valid_manifest(tmp_path):
    """The extension zip holds the manifest and the modules at its root; the manifest has the
    documented fields (a manifest missing one, or with a tagline ending in a full stop, fails the same
    check); where bpy is installed, Blender's own ``extension validate`` accepts the package."""
    import importlib.util
    import tomllib
    import zipfile

    spec = importlib.util.spec_from_file_location("build_zip", ADDON / "build_zip.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    with zipfile.ZipFile(module.build_extension(tmp_path / "ext.zip")) as zf:
        names = set(zf.namelist())
        manifest = tomllib.loads(zf.read("blender_manifest.toml").decode())
    assert {"blender_manifest.toml", "__init__.py", "client.py"} <= names and not any("/" in n for n in names)
    assert _manifest_problems(manifest) == [] and manifest["id"] == "proctex" and "network" in manifest["permissions"]
    broken = {k: v for k, v in manifest.items() if k != "maintainer"}
    assert _manifest_problems({**broken, "tagline": "Ends with a stop."}) == ["missing maintainer", "tagline"]
    if PYTHON is None:
        return
    tool = Path(PYTHON).parents[1] / "lib"
    found = sorted(tool.glob("python3*/site-packages/bpy/*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
    if not found:
        return
    ok = subprocess.run([PYTHON, str(found[0]), "validate", str(ADDON / "proctex_blender")], capture_output=True, text=True, timeout=120)
    assert "Success" in ok.stdout + ok.stderr, ok.stdout + ok.stderr
    bad = tmp_path / "bad"
    bad.mkdir()
    for path in (ADDON / "proctex_blender").glob("*.py"):
        (bad / path.name).write_bytes(path.read_bytes())
    text = (ADDON / "proctex_blender" / "blender_manifest.toml").read_text()
    (bad / "blender_manifest.toml").write_text(text.replace('tagline = "Texture procedural shapes through a ProcTex service"', 'tagline = "Bad."'))
    no = subprocess.run([PYTHON, str(found[0]), "validate", str(bad)], capture_output=True, text=True, timeout=120)
    assert "Success" not in no.stdout + no.stderr and "tagline" in no.stdout + no.stderr


@needs_bpy
@pytest.mark.slow
@pytest.mark.ray
def test_the_addon_textures_the_selected_object_through_a_live_service(served_vase, blends, tmp_path):
    """Headless Blender with the add-on installed from its zip, against ``proctex serve``: the
    family list and parameters fill the panel; "Texture selected" on the moved, turned, scaled Vase
    (new inputs: a ring count no sample had) imports a textured copy with the same transform and the
    same surface, the original hidden, the family's group textures in its materials; pressing it
    again replaces the copy; "Add variant" adds the family's shape; an unreachable service is a
    message in the panel; the look picker lists the family's looks and a variant in the second look
    wears that look's textures (issue 35)."""
    import hashlib
    import io
    import json

    from PIL import Image

    from proctex.store.layout import StoreLayout

    url, store = served_vase
    zip_path = tmp_path / "proctex_blender.zip"
    done = subprocess.run([PYTHON, str(ADDON / "build_zip.py"), str(zip_path)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    out = tmp_path / "report.json"
    env = {
        **__import__("os").environ,
        "BLENDER_USER_SCRIPTS": str(tmp_path / "scripts"),
        "BLENDER_USER_CONFIG": str(tmp_path / "config"),
        "BLENDER_USER_EXTENSIONS": str(tmp_path / "extensions"),
        "PROCTEX_TEST_TOKEN": ADDON_TOKEN,
    }
    done = subprocess.run(
        [PYTHON, str(DRIVER), str(zip_path), str(blends / "vase.blend"), url, "vase", json.dumps({"Resolution": 13, "Height": 1.7}), str(out), "red"],
        capture_output=True,
        text=True,
        timeout=400,
        env=env,
    )
    assert done.returncode == 0 and out.exists(), (done.stdout[-2000:], done.stderr[-3000:])
    report = json.loads(out.read_text())
    assert report["families"] == ["vase"] and all(report["timer_registered"])
    assert set(report["params"]) == {"Height", "Resolution", "Capped"} and report["params"]["Resolution"][0] == "integer"
    assert report["copies"] == 1 and report["copies_after_second"] == 1, report["status"]
    new = report["new"]
    assert new["family"] == "vase" and new["hidden"] and new["hidden_render"]
    assert np.allclose(new["matrix"], new["source_matrix"], atol=1e-6), (new["matrix"], new["source_matrix"])
    src, got = np.array(report["source_world"]), np.array(new["world"])
    assert np.ptp(src[:, 2]) > 1.0 and np.allclose(src.min(0), got.min(0), atol=1e-4) and np.allclose(src.max(0), got.max(0), atol=1e-4)
    from scipy.spatial import cKDTree

    assert cKDTree(src).query(got)[0].max() < 1e-4  # the same surface, where the original stands
    expected = set()
    paint = store.read_json(StoreLayout.PAINT)
    for g in paint["groups"]:
        img = np.asarray(Image.open(io.BytesIO(store.read_bytes(StoreLayout.texture(g["group"], g.get("label") or "")))).convert("RGB"))
        expected.add(hashlib.sha256(np.ascontiguousarray(img[::-1]).tobytes()).hexdigest())  # Blender's rows run bottom-up
    seen = {im["rgb_sha"] for m in new["materials"] for im in m["images"]}
    assert expected and expected <= seen, (expected, new["materials"])
    assert report["variant"] is not None and report["variant"]["faces"] > 0 and report["variant"]["materials"], report["variant_status"]
    assert report["unreachable_status"].startswith("error: cannot reach"), report["unreachable_status"]
    # The look picker fills from the service (the build's look first) and a variant in the "red" look wears its textures.
    assert report["looks"] == ["default", "red"] and report["look"] == "default"
    red = set()
    for g in store.read_json("looks/red/paint.json")["groups"]:
        img = np.asarray(Image.open(io.BytesIO(store.read_bytes(f"looks/red/{Path(StoreLayout.texture(g['group'], g.get('label') or '')).name}"))).convert("RGB"))
        red.add(hashlib.sha256(np.ascontiguousarray(img[::-1]).tobytes()).hexdigest())
    in_red = {im["rgb_sha"] for m in report["look_variant"]["materials"] for im in m["images"]}
    default = {im["rgb_sha"] for m in report["variant"]["materials"] for im in m["images"]}
    assert red <= in_red and not red & default and not expected & in_red, report["look_status"]
    # Issue 53: the active object's image texture (a generated red image) sent as the photo of every
    # part paints a new look; without the token the operator refuses and sends nothing.
    assert "needs the service's edit token" in str(report["photo_without_token"]) and report["photo_ops"] == ["FINISHED"]
    assert "painted from the photo" in report["photo_status"], report["photo_status"]
    assert report["looks_after_photo"] == ["default", "photo", "red"]
    for g in store.read_json("looks/photo/paint.json")["groups"]:
        img = np.asarray(Image.open(io.BytesIO(store.read_bytes(f"looks/photo/{Path(StoreLayout.texture(g['group'], g.get('label') or '')).name}"))).convert("RGB"), float)
        mean = img.reshape(-1, 3).mean(axis=0)
        assert mean[0] > 150 and mean[1] < 80 and mean[2] < 80, mean  # the photo's red (0.9, 0.1, 0.1 linear, as Blender saves it)


# ---------------------------------------------------------------------- real users' files (issue 31)
@needs_bpy
def test_a_model_made_only_of_instances_is_realized_and_only_it_is_evaluated(blends):
    """The rack outputs nothing but instances (Instance on Points, never realized in its graph):
    each cube comes back as a part, the instances' ``part_id`` as the parts, and the file's second,
    heavy object is not evaluated with it (a scene file's other objects cost nothing)."""
    from proctex.sources.blender import BlenderSession

    session = BlenderSession(blends / "rack.blend", "Rack")
    try:
        for count in (2, 5, 8):
            out = session.generate({"Count": count, "Size": 0.3}, parts="part_id")
            assert out.faces.shape == (12 * count, 3) and len(out.vertices) == 8 * count
            assert out.objects == 1  # the model alone, not "Heavy" (a 1500 x 1500 grid)
            assert out.face_parts is not None and len(np.unique(out.face_parts)) == count
            assert out.seconds < 1.0
    finally:
        session.close()
    model = BlenderModel(blends / "rack.blend", "Rack")
    try:
        assert segment(model.generate({"Count": 6})).n_parts == 6
    finally:
        model.close()


@needs_bpy
def test_the_inputs_command_says_which_inputs_need_bounds(blends, tmp_path, capsys):
    import json

    from proctex.cli import main

    spec = tmp_path / "sp.json"
    spec.write_text(json.dumps({"params": {"Count": {"type": "int", "range": [2, 6]}, "Nope": {"type": "bool"}}}))
    assert main(["inputs", str(blends / "rack.blend"), "--object", "Rack", "--params-spec", str(spec), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    rows = {r["name"]: r for r in got["inputs"]}
    assert set(rows) == {"Count", "Size"} and rows["Count"]["type"] == "int" and rows["Count"]["spec"] == {"range": [2, 6]}
    assert not any(r["needs_bounds"] for r in rows.values()) and got["spec_unknown"] == ["Nope"]
    assert main(["inputs", str(blends / "rack.blend"), "--object", "Nothing"]) == 2
    assert "no object 'Nothing'" in capsys.readouterr().err


from tests.data import BLENDS as REAL  # noqa: E402


@needs_bpy
def test_the_real_chair_reads_its_spec_and_paints_the_parts_a_prompt_names():
    """The third-party Geometry Nodes chair (no part names; every input unbounded in Blender): its
    spec gives the ranges and conditions, and "a chair with a red velvet seat and dark walnut legs"
    paints the seat red and the legs dark brown, with no group left a grey default."""
    from proctex.geometry.parts import analyse
    from proctex.store.config import BuildConfig
    from proctex.texture.paint_loop import paint_template

    if not (REAL / "chair.blend").is_file():
        pytest.skip("the shared .blend files are absent")
    cfg = BuildConfig.from_dict({"source": {"blender": {"file": str(REAL / "chair.blend"), "object": "Cube"}, "params_spec": str(REAL / "sp_chair.json")}})
    model = cfg.procedural_model()
    space = model.space
    assert space["Middle Offset"].when == (("Legs Type", 0), ("Has Middle Support", True))
    params = {**space.defaults(), "Has Back": True, "Has Arms": True, "Legs Type": 0, "Back Height": 0.6, "Backrest Scale": 0.7}
    shape = model.generate(params)
    grouping = analyse(shape)
    tex = paint_template(shape, grouping, "a chair with a red velvet seat and dark walnut legs", size=48, up="z")
    by_prompt = {}
    for g in tex.groups:
        c = g.image[g.painted].mean(0)
        by_prompt.setdefault(g.prompt, []).append(c)
        assert c.max() - c.min() > 0.08, (g.group, g.prompt, c)  # no grey default
    assert set(by_prompt) == {"red velvet", "dark walnut"}
    # The node tree names the groups (its node groups "Seat", "Legs", "Back", "Arms"): the prompt
    # lands on the named parts.
    assert {g.label for g in grouping.groups} == {"Seat", "Legs", "Back", "Arms"}
    seat = [g for g in grouping.groups if g.label == "Seat"]
    assert len(seat) == 1 and tex.groups[seat[0].index].prompt == "red velvet"
    legs = [g for g in grouping.groups if g.label == "Legs"]
    assert legs and all(tex.groups[g.index].prompt == "dark walnut" for g in legs)


@needs_bpy
def test_the_real_chair_keeps_its_seat_red_and_legs_dark_on_every_variant():
    """The chair's template painted from the prompt, transferred (no networks: the assignment and
    new-part painting are under test) onto variants with and without back and arms and with each
    leg build: read back per part, the seat is red, the posts and the disc base (a part the template
    lacks) dark brown, and no part (back, arms) is untextured or grey."""
    from proctex.geometry.parts import analyse, connected_parts
    from proctex.store.config import BuildConfig
    from proctex.texture.paint_loop import paint_template
    from proctex.texture.painters import SurfacePainter
    from proctex.texture.uv import sample_texture
    from proctex.transfer.apply import transfer
    from proctex.transfer.assets import prepare_template
    from proctex.transfer.mappers import IdentityMapper

    if not (REAL / "chair.blend").is_file():
        pytest.skip("the shared .blend files are absent")
    prompt = "a chair with a red velvet seat and dark walnut legs"
    cfg = BuildConfig.from_dict({"source": {"blender": {"file": str(REAL / "chair.blend"), "object": "Cube"}, "params_spec": str(REAL / "sp_chair.json")}})
    model = cfg.procedural_model()
    base = {**model.space.defaults(), "Has Back": True, "Has Arms": True, "Legs Type": 0, "Back Height": 0.6, "Backrest Scale": 0.7}
    template = model.generate(base)
    grouping = analyse(template)
    tex = paint_template(template, grouping, prompt, size=48, up="z")
    assets = prepare_template(template, grouping, tex.uv.corner_uv, [g.uint8() for g in tex.groups])
    painter = SurfacePainter(prompt)
    variants = [{"Has Back": False}, {"Has Arms": False}, {"Legs Type": 1}, {"Legs Type": 2, "Has Back": False, "Has Arms": False}, {"Seat Width": 0.7, "Seat Height": 0.75}]
    for change in variants:
        shape = model.generate({**base, **change})
        r = transfer(shape, assets, IdentityMapper(), painter=painter, up="z")
        textures = list(assets.textures) + list(r.new_textures)
        _, labels, n = connected_parts(shape.faces, shape.n_vertices)
        lo, hi = shape.vertices.min(0), shape.vertices.max(0)
        colours, seat, best = {}, None, 0.0
        for p in range(n):
            faces = np.flatnonzero(labels[shape.faces[:, 0]] == p)
            assert (r.face_group[faces] >= 0).all(), (change, p)  # every face textured
            uv = r.corner_uv[faces].mean(axis=1)
            col = np.concatenate([sample_texture(textures[g], uv[r.face_group[faces] == g]) for g in np.unique(r.face_group[faces])])
            mean = colours[p] = col.mean(0)
            assert mean.max() - mean.min() > 0.08 or col.std(0).max() > 0.05, (change, p, mean)  # not a grey default
            pts = shape.vertices[np.unique(shape.faces[faces])]
            ext, z0 = np.ptp(pts, axis=0), (pts[:, 2].min() - lo[2]) / (hi - lo)[2]
            if z0 > 0.3 and ext[0] * ext[1] > best:  # measuring only: the widest part off the floor is the seat
                seat, best = p, ext[0] * ext[1]
            if change.get("Legs Type", 0) == 0 and ext[2] > 3 * max(ext[0], ext[1]) and z0 < 0.05:  # a post on the floor
                assert mean.max() < 0.45 and mean[0] >= mean[2], (change, "leg", mean)  # dark walnut
            if z0 < 0.05 and ext[2] < 0.1 * (hi - lo)[2]:  # a disc base (the template has none): the legs' kin, walnut
                assert mean.max() < 0.45 and mean[0] >= mean[2], (change, "base", mean)
        assert seat is not None, change
        red = colours[seat]
        assert red[0] > red[1] + 0.15 and red[0] > red[2] + 0.15, (change, "seat", red)
