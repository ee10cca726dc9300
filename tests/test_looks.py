"""A family's looks (issue 35): a new prompt painted on the built family's stored template, grouping
and UVs, in seconds, written into its own folder only; transfers with two looks differ in their
textures alone; stores made before looks read as one look, ``default``."""

from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pygltflib as gl
import pytest

from proctex.looks import add_look, remove_look
from proctex.cli import main
from proctex.store.layout import FamilyStore, StoreLayout
from proctex.store.looks import UnknownLook, look_paint, looks, resolve_look
from proctex.store.state import FamilyState, build_stamp, write_config

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture()
def mug(painted_mug_root, tmp_path) -> FamilyStore:
    shutil.copytree(painted_mug_root / "mug", tmp_path / "mug")
    return FamilyStore(tmp_path / "mug")


def tree(folder: Path, skip: str | None = None) -> dict[str, str]:
    """Digest per file under ``folder`` (lock files aside; ``skip``: a sub-folder left out)."""
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file() and ".lock" not in p.name and not (skip and str(p.relative_to(folder)).startswith(skip))
    }


def glb_parts(data: bytes) -> tuple[dict[str, bytes], list[bytes]]:
    """A GLB's geometry (every primitive's attribute and index bytes, by name) and its images' bytes."""
    g = gl.GLTF2.load_from_bytes(data)
    blob = g.binary_blob()

    def view(i: int) -> bytes:
        v = g.bufferViews[i]
        return blob[v.byteOffset or 0 : (v.byteOffset or 0) + v.byteLength]

    geometry = {}
    for m, mesh in enumerate(g.meshes):
        for p, prim in enumerate(mesh.primitives):
            for name, acc in [*vars(prim.attributes).items(), ("indices", prim.indices)]:
                if isinstance(acc, int):
                    geometry[f"{m}/{p}/{name}"] = view(g.accessors[acc].bufferView)
    return geometry, [view(img.bufferView) for img in g.images]


def test_a_store_made_before_looks_reads_as_one_look_default(mug):
    assert not (Path(mug.base) / StoreLayout.LOOKS).exists()
    assert [lk.name for lk in looks(mug)] == ["default"] and resolve_look(mug).built
    assert resolve_look(mug, "default").folder == "template"
    with pytest.raises(UnknownLook, match="the family's looks are: default"):
        resolve_look(mug, "walnut")


def test_the_same_settings_paint_the_same_textures_and_nothing_else_is_written(mug):
    """A look painted with the build's own settings on the stored grouping and UVs is the build's
    look, byte for byte; the store outside ``looks/<name>/`` is untouched."""
    before = tree(Path(mug.base))
    config = FamilyState.load(mug).build_config()
    record = add_look(mug, "again", config.paint, log=lambda *_: None)
    assert record["name"] == "again" and record["paint"]["prompt"] == "blue ceramic"
    assert tree(Path(mug.base), skip="looks/") == before  # nothing outside the new look
    built, again = mug.read_json(StoreLayout.PAINT), mug.read_json("looks/again/paint.json")
    for a, b in zip(built["groups"], again["groups"]):
        assert a["sha256"] == b["sha256"] and a.get("orm_sha256") == b.get("orm_sha256")
        assert (Path(mug.base) / StoreLayout.texture(a["group"], a["label"])).read_bytes() == (Path(mug.base) / "looks/again" / Path(StoreLayout.texture(a["group"], a["label"])).name).read_bytes()
    assert not list(Path(mug.base).rglob("*.tmp-*"))


def test_two_looks_transfer_the_same_geometry_and_uvs_with_other_textures(mug, tmp_path, capsys):
    assert main(["look", "add", mug.base, "walnut", "--prompt", "dark walnut wood", "--json"]) == 0
    added = json.loads(capsys.readouterr().out)["look"]
    assert added["paint"]["prompt"] == "dark walnut wood" and added["seconds"] > 0
    out = {}
    for look in (None, "walnut"):
        path = tmp_path / f"{look}.glb"
        argv = ["transfer", mug.base, "--params", json.dumps({"radius": 0.045}), "--out", str(path), "--json"]
        assert main(argv + (["--look", look] if look else [])) == 0
        assert json.loads(capsys.readouterr().out)["look"] == (look or "default")
        out[look] = glb_parts(path.read_bytes())
    (geo_a, img_a), (geo_b, img_b) = out[None], out["walnut"]
    assert geo_a.keys() == geo_b.keys() and {k.rsplit("/", 1)[1] for k in geo_a} >= {"POSITION", "TEXCOORD_0", "indices"}
    assert all(geo_a[k] == geo_b[k] for k in geo_a)  # geometry and UVs byte for byte
    assert len(img_a) == len(img_b) and all(a != b for a, b in zip(img_a, img_b))  # every texture differs
    assert main(["transfer", mug.base, "--params", "{}", "--out", str(tmp_path / "x.glb"), "--look", "nope"]) == 2
    assert "unknown look 'nope'; the family's looks are: default, walnut" in capsys.readouterr().err


def test_look_list_add_rm_and_their_refusals(mug, capsys):
    quiet = lambda *_: None  # noqa: E731
    paint = replace(FamilyState.load(mug).build_config().paint, prompt="red lacquer")
    stamp = build_stamp(mug)
    add_look(mug, "red", paint, log=quiet)
    assert build_stamp(mug) != stamp  # a service notices the new look
    assert main(["look", "list", mug.base, "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)["looks"]
    assert [(r["name"], r["built"], r["prompt"]) for r in rows] == [("default", True, "blue ceramic"), ("red", False, "red lacquer")]
    assert look_paint(mug, resolve_look(mug, "red"), paint).prompt == "red lacquer"
    before = tree(Path(mug.base))
    for argv, message in (
        (["look", "add", mug.base, "red", "--prompt", "x"], "has a look 'red' already; --force"),
        (["look", "add", mug.base, "default", "--prompt", "x"], "the build's look"),
        (["look", "add", mug.base, "a/b", "--prompt", "x"], "a look's name"),
        (["look", "add", mug.base, "x.tmp-1", "--prompt", "x"], "a look's name"),
        (["look", "add", mug.base, "ok", "--prompt", "  "], "needs --prompt"),
        (["look", "add", mug.base, "ok", "--prompt", "x", "--texture-size", "3"], "texture_size"),
        (["look", "rm", mug.base, "default"], "cannot be removed"),
        (["look", "rm", mug.base, "nope"], "unknown look"),
    ):
        assert main(argv) == 2, argv
        assert message in capsys.readouterr().err, argv
    assert tree(Path(mug.base)) == before  # refusals write nothing
    add_look(mug, "red", replace(paint, prompt="green lacquer"), force=True, log=quiet)
    assert look_paint(mug, resolve_look(mug, "red"), paint).prompt == "green lacquer"
    remove_look(mug, "red")
    assert [lk.name for lk in looks(mug)] == ["default"] and not (Path(mug.base) / "looks" / "red").exists()


def test_a_damaged_look_fails_alone(mug):
    from proctex.serve.service import FamilyService
    from proctex.store.layout import StoreDamaged

    add_look(mug, "red", replace(FamilyState.load(mug).build_config().paint, prompt="red"), log=lambda *_: None)
    tex = next((Path(mug.base) / "looks" / "red").glob("group_0*.png"))
    tex.write_bytes(tex.read_bytes()[:-8] + b"damaged!")
    with pytest.raises(StoreDamaged):
        FamilyService(mug, look="red")
    assert FamilyService(mug).look.name == "default"  # the build's look still serves


def test_two_processes_adding_looks_at_once_both_land(mug):
    code = (
        "import sys\nfrom dataclasses import replace\nfrom proctex.looks import add_look\nfrom proctex.store.layout import FamilyStore\n"
        "from proctex.store.state import FamilyState\nst = FamilyStore(sys.argv[1])\n"
        "add_look(st, sys.argv[2], replace(FamilyState.load(st).build_config().paint, prompt=sys.argv[2]), log=lambda *_: None)\n"
    )
    procs = [subprocess.Popen([sys.executable, "-c", code, mug.base, name], cwd=ROOT, stderr=subprocess.PIPE, text=True) for name in ("oak", "teak")]
    for p in procs:
        _, err = p.communicate(timeout=300)
        assert p.returncode == 0, err[-2000:]
    assert [lk.name for lk in looks(mug)] == ["default", "oak", "teak"]


def test_a_build_with_another_prompt_points_at_look_add(mug):
    config = FamilyState.load(mug).build_config()
    with pytest.raises(ValueError, match="proctex look add"):
        write_config(mug, replace(config, paint=replace(config.paint, prompt="white oak")))
    with pytest.raises(ValueError, match="built with another config; use a new folder"):
        write_config(mug, replace(config, seed=config.seed + 1))


def test_the_look_record_keeps_what_painted_it(mug):
    add_look(mug, "red", replace(FamilyState.load(mug).build_config().paint, prompt="red", group_prompts={"0": "black"}), log=lambda *_: None)
    record = mug.read_json("looks/red/look.json")
    assert record["paint"]["group_prompts"] == {"0": "black"} and record["coverage"] >= 0
    summary = mug.read_json("looks/red/paint.json")
    assert summary["look"] == "red" and summary["groups"][0]["prompt"] == "black"
    assert record["seconds"] > 0


def test_an_edit_of_one_look_leaves_the_others_and_undoes_alone(mug, capsys):
    from proctex.serve.edits import undo_edit

    add_look(mug, "red", replace(FamilyState.load(mug).build_config().paint, prompt="red"), log=lambda *_: None)
    built = tree(Path(mug.base), skip="looks/")
    red = tree(Path(mug.base) / "looks" / "red")
    assert main(["edit", mug.base, "--group", "0", "--hue", "40", "--look", "red"]) == 0
    assert "of look red" in capsys.readouterr().out
    assert tree(Path(mug.base), skip="looks/") == built  # the build's look untouched
    assert tree(Path(mug.base) / "looks" / "red") != red
    assert mug.read_json("looks/red/paint.json")["edits"][0]["version"] == 1 and not mug.read_json(StoreLayout.PAINT).get("edits")
    undo_edit(mug, look="red")
    assert tree(Path(mug.base) / "looks" / "red") == red  # the look as it was painted
    assert main(["edit", mug.base, "--group", "0", "--hue", "40", "--look", "nope"]) == 2


def test_the_looks_benchmark_writes_its_report(painted_mug_root, tmp_path):
    out = tmp_path / "looks.json"
    done = subprocess.run(
        [sys.executable, str(ROOT / "tests" / "bench" / "bench_looks.py"), "--family", str(painted_mug_root / "mug"), "--work", str(tmp_path / "work"), "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=ROOT,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    rep = json.loads(out.read_text())
    assert len(rep["look_seconds"]) == 3 and rep["look_median_seconds"] > 0 and rep["machine"]["cpus"] >= 1
    assert (painted_mug_root / "mug" / "looks").exists() is False  # the family given was copied, not changed


def test_eval_measures_a_look_and_keeps_its_figures_beside_it(mug, capsys):
    """The colour metrics are per look: a look painted with the build's settings measures the same
    tracked-point variance as the build's look; the family's metrics.json stays the build's."""
    config = FamilyState.load(mug).build_config()
    add_look(mug, "again", config.paint, log=lambda *_: None)
    add_look(mug, "stripes", replace(config.paint, prompt="black and white zebra stripes"), log=lambda *_: None)
    figures = {}
    for look in (None, "again", "stripes"):
        argv = ["eval", mug.base, "--methods", "identity", "--shapes", "train", "--limit", "1", "--tracked", "200", "--json"]
        assert main(argv + (["--look", look] if look else [])) == 0
        figures[look] = json.loads(capsys.readouterr().out)
    assert figures["again"]["look"] == "again" and figures[None]["look"] == "default"
    var = {k: v["methods"]["identity"]["tracked_point_variance"] for k, v in figures.items()}
    assert var["again"] == pytest.approx(var[None], abs=1e-12) and var["stripes"] != pytest.approx(var[None], abs=1e-6)
    assert mug.read_json(StoreLayout.METRICS)["look"] == "default"
    assert mug.read_json("looks/stripes/metrics.json")["look"] == "stripes"


def test_the_service_lists_adds_and_serves_looks_without_a_restart(mug):
    """Over HTTP: a look added while serving is served at once (``?look=``); linked answers name the
    look in their texture URIs and those URIs give the look's textures; per-look edits; clear errors."""
    import asyncio
    from urllib.parse import urljoin

    httpx = pytest.importorskip("httpx")
    from proctex.serve.catalog import Catalog
    from workers.http import create_app

    cat = Catalog(str(Path(mug.base).parent), check_every=0)
    app = create_app(lambda: cat, edit_token="look-token-1")
    token = {"X-ProcTex-Token": "look-token-1"}

    async def run():
        async with httpx.AsyncClient(transport=httpx.ASGITransport(app=app), base_url="http://t", timeout=60) as c:
            first = (await c.get("/v1/families/mug/looks")).json()["looks"]
            denied = await c.post("/v1/families/mug/looks", json={"name": "walnut", "prompt": "dark walnut"})
            added = await c.post("/v1/families/mug/looks", json={"name": "walnut", "prompt": "dark walnut"}, headers=token)
            again = await c.post("/v1/families/mug/looks", json={"name": "walnut", "prompt": "x"}, headers=token)
            bad = [
                await c.post("/v1/families/mug/looks", json=b, headers=token)
                for b in (
                    {"name": "../x", "prompt": "x"},
                    {"name": "ok", "prompt": ""},
                    {"name": "ok", "prompt": "x", "texture_size": 100000},
                    {"name": "ok", "prompt": "x", "shader": 1},
                    {"name": "ok", "prompt": "x", "painter": "nope"},
                )
            ]
            looks_after = (await c.get("/v1/families/mug/looks")).json()["looks"]
            plain = await c.post("/v1/families/mug/transfer", json={"params": {}})
            walnut = await c.post("/v1/families/mug/transfer?look=walnut", json={"params": {}})
            linked = await c.post("/v1/families/mug/transfer?look=walnut&textures=linked", json={"params": {}})
            unknown = await c.post("/v1/families/mug/transfer?look=nope", json={"params": {}})
            described = (await c.get("/v1/families/mug?look=walnut")).json()
            g = gl.GLTF2.load_from_bytes(linked.content)
            uri = g.images[0].uri
            tex = await c.get(urljoin("/v1/families/mug/transfer", uri))
            built_tex = await c.get("/v1/families/mug/textures/0.png")
            edit = await c.post("/v1/families/mug/edits?look=walnut", json={"group": 0, "hue": 30}, headers=token)
            walnut_after = (await c.get("/v1/families/mug?look=walnut")).json()
            built_after = (await c.get("/v1/families/mug")).json()
            undo = await c.delete("/v1/families/mug/edits/last?look=walnut", headers=token)
            return (first, denied, added, again, bad, looks_after, plain, walnut, linked, unknown, described, uri, tex, built_tex, edit, walnut_after, built_after, undo)

    (first, denied, added, again, bad, looks_after, plain, walnut, linked, unknown, described, uri, tex, built_tex, edit, walnut_after, built_after, undo) = asyncio.run(run())
    assert [lk["name"] for lk in first] == ["default"]
    assert denied.status_code == 401 and added.status_code == 200 and added.json()["look"]["paint"]["prompt"] == "dark walnut"
    assert again.status_code == 422 and "--force" in again.json()["error"]
    assert [r.status_code for r in bad] == [422] * 5 and all("error" in r.json() for r in bad)
    assert [lk["name"] for lk in looks_after] == ["default", "walnut"]
    assert plain.status_code == walnut.status_code == 200
    (geo_a, img_a), (geo_b, img_b) = glb_parts(plain.content), glb_parts(walnut.content)
    assert geo_a == geo_b and img_a != img_b
    assert unknown.status_code == 404 and "the family's looks are: default, walnut" in unknown.json()["error"]
    assert described["look"] == "walnut" and described["prompt"] == "dark walnut" and described["looks"] == ["default", "walnut"]
    assert "look=walnut" in uri and tex.status_code == 200 and tex.content == img_b[0] and tex.content != built_tex.content
    assert tex.headers["etag"] != built_tex.headers["etag"]
    assert edit.status_code == 200 and walnut_after["edits"] == 1 and built_after["edits"] == 0
    assert undo.status_code == 200 and undo.json()["undone"][0]["version"] == 1


def test_generate_crosses_shapes_with_looks_and_every_row_wears_its_look(mug, tmp_path, capsys):
    """Issue 35's dataset case: 2 looks x 50 shapes = 100 rows; each row's look column names the
    look whose textures its GLB carries (byte for byte the look's stored PNGs), and the two GLBs
    of one shape share their geometry."""
    import pyarrow.parquet as pq

    add_look(mug, "red", replace(FamilyState.load(mug).build_config().paint, prompt="red lacquer"), log=lambda *_: None)
    out = tmp_path / "gen"
    assert main(["generate", mug.base, "--n", "50", "--looks", "default,red", "--out", str(out), "--quiet", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    rows = pq.read_table(out / "manifest.parquet").to_pylist()
    assert summary["written"] == 100 and len(rows) == 100
    assert [r["look"] for r in rows] == ["default", "red"] * 50 and len({r["id"] for r in rows}) == 100
    stored = {look.name: [p for p in sorted((Path(mug.base) / look.folder).glob("group_*.png")) if p.name.count(".") == 1] for look in looks(mug)}
    stored = {name: {p.read_bytes() for p in paths} for name, paths in stored.items()}
    by_shape: dict[str, dict[str, tuple]] = {}
    for r in rows:
        geometry, images = glb_parts((out / r["file"]).read_bytes())
        other = "red" if r["look"] == "default" else "default"
        assert stored[r["look"]] <= set(images) and not stored[other] & set(images)  # its look's textures, none of the other's
        by_shape.setdefault(r["params"], {})[r["look"]] = geometry
    assert len(by_shape) == 50 and all(v["default"] == v["red"] for v in by_shape.values())


def test_generate_shared_textures_per_look_rows_files_and_random_looks(mug, tmp_path, capsys):
    import pyarrow as pa
    import pyarrow.parquet as pq

    add_look(mug, "red", replace(FamilyState.load(mug).build_config().paint, prompt="red lacquer"), log=lambda *_: None)
    shared = tmp_path / "shared"
    assert main(["generate", mug.base, "--n", "2", "--looks", "all", "--textures", "shared", "--out", str(shared), "--quiet"]) == 0
    assert (shared / "textures" / "0.png").read_bytes() != (shared / "textures" / "red" / "0.png").read_bytes()
    uris = {r["look"]: gl.GLTF2.load_from_bytes((shared / r["file"]).read_bytes()).images[0].uri for r in pq.read_table(shared / "manifest.parquet").to_pylist()}
    assert uris == {"default": "../textures/0.png", "red": "../textures/red/0.png"}
    rows_file = tmp_path / "rows.parquet"
    pq.write_table(pa.table({"radius": [0.04, 0.05, 0.045], "look": ["red", "nope", None]}), rows_file)
    by_rows = tmp_path / "by_rows"
    assert main(["generate", mug.base, "--rows", str(rows_file), "--out", str(by_rows), "--quiet"]) == 0
    rows = pq.read_table(by_rows / "manifest.parquet").to_pylist()
    assert [(r["look"], r["status"]) for r in rows] == [("red", "written"), ("nope", "failed"), ("default", "written")]
    assert "unknown look 'nope'" in rows[1]["error"]
    capsys.readouterr()
    assert main(["generate", mug.base, "--n", "2", "--looks", "walnut", "--out", str(tmp_path / "x"), "--quiet"]) == 2
    assert "unknown look 'walnut'" in capsys.readouterr().err and not (tmp_path / "x" / "variants").exists()
    rand = tmp_path / "rand"
    assert main(["generate", mug.base, "--n", "2", "--random-looks", "2", "--seed", "5", "--out", str(rand), "--quiet"]) == 0
    made = {lk.name: look_paint(mug, lk, FamilyState.load(mug).build_config().paint).prompt for lk in looks(mug)}
    from proctex.texture.painters.vocabulary import random_prompts

    assert [made["random-5-0"], made["random-5-1"]] == random_prompts(2, 5)
    assert {r["look"] for r in pq.read_table(rand / "manifest.parquet").to_pylist()} == {"random-5-0", "random-5-1"}
    assert main(["generate", mug.base, "--n", "2", "--random-looks", "2", "--seed", "5", "--out", str(rand), "--quiet"]) == 0  # resumes


def test_random_prompts_are_seeded_distinct_and_understood():
    from proctex.texture.painters.prompt import parse_prompt
    from proctex.texture.painters.vocabulary import random_prompts

    prompts = random_prompts(100, seed=1)
    assert prompts == random_prompts(100, seed=1) and prompts != random_prompts(100, seed=2) and len(set(prompts)) == 100
    for p in prompts:
        assert parse_prompt(p).ignored == (), p  # every word is the painter's
    kinds = {parse_prompt(p).material for p in prompts}
    assert {"wood", "metal", "ceramic"} <= kinds and len(kinds) >= 6
    with pytest.raises(ValueError):
        random_prompts(-1)


def test_sheet_shows_a_look(mug, tmp_path, capsys):
    add_look(mug, "red", replace(FamilyState.load(mug).build_config().paint, prompt="red lacquer"), log=lambda *_: None)
    sheet = tmp_path / "sheet"
    argv = ["sheet", mug.base, "--out", str(sheet), "--rows", "1", "--per-row", "2", "--frames", "2", "--size", "64", "--quiet"]
    assert main(argv + ["--look", "red"]) == 0
    s = json.loads((sheet / "demo.json").read_text())
    assert s["look"] == "red" and s["prompt"] == "red lacquer"
    red = {p.read_bytes() for p in (Path(mug.base) / "looks" / "red").glob("group_*.png") if p.name.count(".") == 1}
    assert red <= set(glb_parts((sheet / s["variants"][0]["glb"]).read_bytes())[1])
    assert main(["sheet", mug.base, "--out", str(tmp_path / "bad"), "--look", "nope", "--quiet"]) == 2
    assert "unknown look 'nope'" in capsys.readouterr().err and not (tmp_path / "bad").exists()


def test_a_store_without_looks_serves_as_before_and_a_new_look_changes_nothing_of_it(mug):
    """The fixture is a store as every build made it before looks (no look key, no looks/): its
    transfer is the same bytes through the build's look by name, and after another look is added."""
    from proctex.serve.service import FamilyService

    assert "look" not in mug.read_json(StoreLayout.PAINT)
    shape = FamilyState.load(mug).build_config().procedural_model().generate({"radius": 0.045})
    before = FamilyService(mug).transfer(shape)[0]
    assert FamilyService(mug, look="default").transfer(shape)[0] == before
    add_look(mug, "red", replace(FamilyState.load(mug).build_config().paint, prompt="red"), log=lambda *_: None)
    svc = FamilyService(mug)
    assert svc.transfer(shape)[0] == before and svc.look_view("default") is svc
    assert svc.look_view("red").transfer(shape)[0] != before


def test_build_names_its_look(tmp_path, capsys):
    argv = ["build", "--model", "mug", "--n-train", "2", "--n-test", "0", "--texture-size", "32", "--prompt", "blue ceramic", "--stages", "sample,template,paint", "--out", str(tmp_path / "m")]
    assert main(argv + ["--look", "a/b"]) == 2 and "a look's name" in capsys.readouterr().err
    assert not (tmp_path / "m").exists()  # refused before any work
    assert main(argv + ["--look", "ceramic"]) == 0 and "its look: ceramic" in capsys.readouterr().out
    st = FamilyStore(tmp_path / "m")
    assert [lk.name for lk in looks(st)] == ["ceramic"] and resolve_look(st, "ceramic").built
    add_look(st, "red", replace(FamilyState.load(st).build_config().paint, prompt="red"), log=lambda *_: None)
    assert main(argv + ["--look", "red"]) == 2 and "another look called 'red'" in capsys.readouterr().err


def test_a_look_is_painted_under_its_limits_and_nothing_is_written_past_them(mug, tmp_path):
    """A look's texels and the family's count are checked before any work, its time while it paints
    (a budget cancelled, as when the client leaves, or run out: it stops between groups) and its
    bytes before anything is written; each refusal leaves the family as it was."""
    import threading

    from proctex.looks import LookLimits, LookOverLimit
    from proctex.store.looks import new_look_paint
    from proctex.transfer.budget import Budget, OverBudget

    root = Path(mug.base)
    build = FamilyState.load(mug).build_config(mug.uri).paint
    paint = new_look_paint(build, "red oak")
    before = tree(root)
    with pytest.raises(LookOverLimit, match="texels, over the limit") as err:
        add_look(mug, "big", replace(paint, texture_size=2048), limits=LookLimits(texels=2048 * 2048))
    assert err.value.kind == "size" and tree(root) == before
    with pytest.raises(LookOverLimit, match="bytes of files, over the limit"):
        add_look(mug, "fat", paint, limits=LookLimits(bytes=1000))
    assert tree(root) == before
    gone = Budget(60.0)
    gone.cancel()  # the client left before the paint began
    with pytest.raises(OverBudget, match="cancelled") as err:
        add_look(mug, "left", paint, budget=gone)
    assert err.value.cancelled and tree(root) == before
    # cancelled while painting: the groups under way finish, no other starts
    late, seen = Budget(60.0), []
    real = late.check

    def check(what):
        seen.append(what)
        if what.startswith("painting part group 2"):
            threading.Thread(target=late.cancel).start()
            threading.Event().wait(0.2)
        real(what)

    late.check = check
    with pytest.raises(OverBudget, match="cancelled"):
        add_look(mug, "late", paint, budget=late)
    assert tree(root) == before and not any(w.startswith("encoding") for w in seen), seen
    with pytest.raises(OverBudget, match="over the time budget of 1e-06 s"):
        add_look(mug, "slow", paint, limits=LookLimits(seconds=1e-6))
    assert tree(root) == before
    add_look(mug, "one", paint, limits=LookLimits(looks=1))
    with pytest.raises(LookOverLimit, match="its most \\(1\\)") as err:
        add_look(mug, "two", paint, limits=LookLimits(looks=1))
    assert err.value.kind == "count"
    add_look(mug, "one", new_look_paint(build, "blue oak"), force=True, limits=LookLimits(looks=1))  # a replacement counts once
    for bad in ({"seconds": 0}, {"texels": 0}, {"bytes": -1}, {"looks": True}):
        with pytest.raises(ValueError):
            LookLimits(**bad)


def test_the_service_paints_looks_under_its_limits(mug):
    """Over HTTP the same limits come from the service's Limits: over the texels 413, over the count
    409, over the time 422, each with nothing written."""
    from fastapi.testclient import TestClient

    from proctex.serve.catalog import Catalog
    from proctex.serve.service import Limits
    from workers.http import create_app

    root = Path(mug.base)
    head = {"X-ProcTex-Token": "tok"}
    before = tree(root)

    def client(**limits):
        cat = Catalog(str(root.parent), Limits(**limits), check_every=0)
        return TestClient(create_app(lambda: cat, edit_token="tok"))

    r = client(look_texels=1000).post(f"/v1/families/{root.name}/looks", json={"name": "a", "prompt": "oak"}, headers=head)
    assert r.status_code == 413 and "texels" in r.json()["error"] and tree(root) == before, r.text
    r = client(look_seconds=1e-6).post(f"/v1/families/{root.name}/looks", json={"name": "a", "prompt": "oak"}, headers=head)
    assert r.status_code == 422 and "time budget" in r.json()["error"] and tree(root) == before, r.text
    c = client(max_looks=1)
    assert c.post(f"/v1/families/{root.name}/looks", json={"name": "a", "prompt": "oak"}, headers=head).status_code == 200
    r = c.post(f"/v1/families/{root.name}/looks", json={"name": "b", "prompt": "oak"}, headers=head)
    assert r.status_code == 409 and "most (1)" in r.json()["error"], r.text


def test_look_add_takes_its_limits_on_the_command_line(mug, capsys):
    root = Path(mug.base)
    assert main(["look", "add", str(root), "a", "--prompt", "oak"]) == 0
    before = tree(root)
    assert main(["look", "add", str(root), "b", "--prompt", "oak", "--max-looks", "1"]) == 2
    assert "its most (1)" in capsys.readouterr().err and tree(root) == before
    assert main(["look", "add", str(root), "b", "--prompt", "oak", "--max-seconds", "0.000001"]) == 2
    assert "time budget" in capsys.readouterr().err and tree(root) == before
    assert main(["look", "add", str(root), "b", "--prompt", "oak", "--max-seconds", "-1"]) == 2
    assert "positive" in capsys.readouterr().err
    assert main(["look", "add", str(root), "b", "--prompt", "oak", "--max-looks", "2"]) == 0
