"""Every write lands and is reported, or does not land and is reported (issue 34): edits and undos
on a full disk change nothing and answer 507; a texture changed outside ProcTex is refused, never
recorded; every edit path (the CLI's included) is versioned and undoable; nonsense placements are
refused before anything is read."""

from __future__ import annotations

import errno
import hashlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from proctex.serve.catalog import Catalog
from proctex.serve.edits import edit_group, undo_edit
from proctex.store.layout import FamilyStore, StoreDamaged, StoreLayout, StoreWriteError

TOKEN = {"X-ProcTex-Token": "tok"}


class FullDisk:
    """A file system that runs out of space after ``room`` more files (``room`` None: never)."""

    def __init__(self, fs, state):
        self._fs, self._state = fs, state

    def open_output_stream(self, path, *a, **k):
        room = self._state.get("room")
        if room is not None:
            if room <= 0:
                raise OSError(errno.ENOSPC, "No space left on device", path)
            self._state["room"] = room - 1
        return self._fs.open_output_stream(path, *a, **k)

    def __getattr__(self, name):
        return getattr(self._fs, name)


@pytest.fixture()
def family(painted_mug_root, tmp_path, monkeypatch):
    """A copy of the painted mug whose stores all write through :class:`FullDisk`."""
    root = tmp_path / "root"
    shutil.copytree(painted_mug_root / "mug", root / "mug")
    state: dict = {"room": None}
    real = FamilyStore.__init__

    def init(self, r):
        real(self, r)
        self.fs = FullDisk(self.fs, state)

    monkeypatch.setattr(FamilyStore, "__init__", init)
    return root, state


def tree(folder: Path) -> dict[str, str]:
    """Every file under ``folder`` (lock files aside) by its checksum, and every folder (a failed
    write leaves no empty folder either)."""
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "folder" for p in sorted(folder.rglob("*")) if (p.is_file() and ".lock" not in p.name) or p.is_dir()
    }


@pytest.mark.parametrize("room", [0, 1, 3, 5])
def test_an_edit_on_a_full_disk_changes_nothing_and_says_so(family, room):
    root, state = family
    fam = root / "mug"
    before = tree(fam)
    state["room"] = room  # the disk fills after `room` of the edit's files
    with pytest.raises(StoreWriteError, match="no space left.*nothing was changed") as err:
        edit_group(FamilyStore(fam), 0, hue=40)
    assert err.value.errno == errno.ENOSPC
    assert tree(fam) == before  # no texture, no record, no orphan snapshot, no temporary
    state["room"] = None
    record = edit_group(FamilyStore(fam), 0, hue=40)  # with room again the same edit lands
    assert record["version"] == 1 and tree(fam) != before


def test_an_undo_on_a_full_disk_is_not_half_applied(family):
    root, state = family
    st = FamilyStore(root / "mug")
    edit_group(st, 0, hue=40)
    edited = tree(root / "mug")
    state["room"] = 1
    with pytest.raises(StoreWriteError):
        undo_edit(st)
    assert tree(root / "mug") == edited and len(st.read_json(StoreLayout.PAINT)["edits"]) == 1
    state["room"] = None
    assert undo_edit(st)["version"] == 1 and not st.read_json(StoreLayout.PAINT).get("edits")


def test_the_service_answers_507_for_a_full_disk_and_503_for_a_tampered_texture(family):
    from fastapi.testclient import TestClient

    from workers.http import create_app

    root, state = family
    cat = Catalog(str(root), check_every=0)
    c = TestClient(create_app(lambda: cat, edit_token="tok"))
    assert c.post("/v1/families/mug/edits", json={"group": 0, "hue": 10}, headers=TOKEN).status_code == 200
    edited = tree(root / "mug")
    state["room"] = 2
    for call in (lambda: c.post("/v1/families/mug/edits", json={"group": 0, "hue": 10}, headers=TOKEN), lambda: c.delete("/v1/families/mug/edits/last", headers=TOKEN)):
        r = call()
        assert r.status_code == 507 and "nothing was changed" in r.json()["error"], r.text
        assert tree(root / "mug") == edited
    state["room"] = None
    # Another valid PNG of the same size put in place of group 0's texture while the family is served.
    st = FamilyStore(root / "mug")
    g = st.read_json(StoreLayout.PAINT)["groups"][0]
    rel = StoreLayout.texture(0, g["label"])
    from proctex.fileio import encode_png
    from proctex.store.template import decode_png

    tampered = encode_png(255 - decode_png(st.read_bytes(rel), rel))
    (root / "mug" / rel).write_bytes(tampered)
    r = c.post("/v1/families/mug/edits", json={"group": 0, "hue": 20}, headers=TOKEN)
    assert r.status_code == 503 and "checksum mismatch" in r.json()["error"] and rel.split("/")[-1] in r.json()["error"]
    assert st.read_bytes(rel) == tampered and len(st.read_json(StoreLayout.PAINT)["edits"]) == 1  # refused, not laundered
    with pytest.raises(StoreDamaged):
        edit_group(st, 0, hue=20)


@pytest.mark.parametrize("damaged", ["template/uv.npz", "family.json"])
def test_an_edit_over_a_truncated_store_file_answers_503_like_any_damage(family, damaged):
    """A store file an edit reads cut short (uv.npz, family.json) is damage (503, the file
    named), not the client's error (422), and nothing is written."""
    from fastapi.testclient import TestClient

    from workers.http import create_app

    root, _ = family
    cat = Catalog(str(root), check_every=0)
    c = TestClient(create_app(lambda: cat, edit_token="tok"))
    assert c.get("/v1/families/mug").status_code == 200  # served, then damaged underneath
    path = root / "mug" / damaged
    path.write_bytes(path.read_bytes()[: max(1, path.stat().st_size // 2)])
    before = tree(root / "mug")
    r = c.post("/v1/families/mug/edits", json={"group": 0, "hue": 10}, headers=TOKEN)
    assert r.status_code == 503 and damaged.split("/")[-1] in r.json()["error"], r.text
    assert tree(root / "mug") == before


def test_every_edit_path_is_versioned_the_cli_included(family, capsys):
    from proctex.cli import main

    root, _ = family
    fam = str(root / "mug")
    assert main(["edit", fam, "--group", "0", "--hue", "30"]) == 0
    edits = FamilyStore(fam).read_json(StoreLayout.PAINT)["edits"]
    assert edits[-1]["version"] == 1 and edits[-1]["before"] != edits[-1]["after"]
    assert undo_edit(FamilyStore(fam))["version"] == 1  # an edit made from the CLI can be undone


def test_nonsense_placements_are_refused_before_anything_changes(family, tmp_path, capsys):
    from proctex.cli import main
    from proctex.fileio import encode_png

    root, _ = family
    fam = root / "mug"
    logo = tmp_path / "logo.png"
    logo.write_bytes(encode_png(np.zeros((8, 8, 3), np.uint8)))
    before = tree(fam)
    for flags, message in (
        (["--size", "1e9,1e9"], "size must be two numbers in (0, 1]"),
        (["--size", "0,0.2"], "size"),
        (["--at", "2,0.5"], "at must be two numbers in [0, 1]"),
        (["--opacity", "3"], "opacity"),
        (["--rotation", "nan"], "rotation"),
    ):
        assert main(["edit", str(fam), "--group", "0", "--logo", str(logo), *flags]) == 2, flags
        assert message in capsys.readouterr().err, flags
    assert tree(fam) == before


def test_damage_repaired_on_disk_is_noticed_without_a_restart(family):
    """A damaged family answers 503; once its file is put back byte for byte the catalog serves it
    again after its back-off (and not before), with no restart."""
    import time

    from proctex.serve.service import Unavailable

    root, _ = family
    st = FamilyStore(root / "mug")
    rel = StoreLayout.texture(0, st.read_json(StoreLayout.PAINT)["groups"][0]["label"])
    good = st.read_bytes(rel)
    (root / "mug" / rel).write_bytes(good[:40])  # damaged
    cat = Catalog(str(root), check_every=0, recheck_after=0.2)
    with pytest.raises(Unavailable, match="checksum mismatch"):
        cat.get("mug")
    (root / "mug" / rel).write_bytes(good)  # repaired
    with pytest.raises(Unavailable):
        cat.get("mug")  # within the back-off: the known answer, no reload
    loads = cat.loads
    time.sleep(0.25)
    assert cat.get("mug").name == "mug" and cat.loads == loads + 1 and cat.health() == {"mug": "ok"}


HOLD = """
import sys, time
from proctex.store.layout import FamilyStore
from proctex.store.locks import build_lock
with build_lock(FamilyStore(sys.argv[1]), "a build"):
    print("held", flush=True)
    time.sleep(120)
"""


def test_a_store_is_built_by_one_process_at_a_time_and_a_dead_holder_frees_it(family, tmp_path, capsys):
    """A build (or an edit) of a store another process is building is refused, naming the holder;
    the config check runs under the lock; once the holder dies (SIGKILL: no clean-up) the lock is
    free and the next build takes it."""
    import os
    import signal
    import subprocess
    import sys

    from proctex.cli import main
    from proctex.serve.edits import EditConflict

    root, _ = family
    fam = root / "mug"
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(fam)], stdout=subprocess.PIPE, text=True, env=env)
    try:
        assert holder.stdout.readline().strip() == "held"
        assert main(["build", "--model", "mug", "--prompt", "red", "--out", str(fam), "--n-train", "2", "--n-test", "0"]) == 2
        err = capsys.readouterr().err
        assert "held by a build" in err and f"pid {holder.pid}" in err, err
        with pytest.raises(EditConflict, match="held by a build"):
            edit_group(FamilyStore(fam), 0, hue=10)
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    assert edit_group(FamilyStore(fam), 0, hue=10)["version"] == 1  # the dead holder's lock is free


def test_nonsense_numbers_and_meshes_that_cannot_be_served_get_clear_errors(family, tmp_path, capsys):
    """`proctex transfer --bake -5 / 100000 / --seed -1` are refused before any work; a mesh whose
    positions cannot be served as float32 without losing its shape (moved 1e9 away, scaled by
    1e300, collapsed to a point) is refused naming the problem, and a sound one is served (the
    check can pass)."""
    from proctex.cli import main
    from proctex.models import get_model
    from proctex.serve.service import BadInput, FamilyService

    root, _ = family
    fam = str(root / "mug")
    for flags, message in ((["--bake", "-5"], "bake"), (["--bake", "100000"], "bake size"), (["--seed", "-1"], "seed")):
        out = tmp_path / "x.glb"
        assert main(["transfer", fam, "--params", "{}", "--out", str(out), *flags]) == 2, flags
        assert message in capsys.readouterr().err and not out.exists(), flags
    svc = FamilyService(FamilyStore(fam))
    mug = get_model("mug").generate()

    def obj_text(vertices, faces):  # every digit kept, as an exporter writes a far-away mesh
        return "".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in vertices.tolist()) + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces.tolist())

    for vertices, message in ((mug.vertices + 1e9, "float32 positions would collapse it"), (mug.vertices * 1e300, "from the origin"), (mug.vertices * 0 + 1.0, "no extent")):
        with pytest.raises(BadInput, match=message):
            svc.shape_from_mesh(obj_text(vertices, mug.faces).encode(), "m.obj")
    ok = svc.shape_from_mesh(obj_text(mug.vertices + 1e3, mug.faces).encode(), "m.obj")  # a kilometre away is fine
    assert svc.textured(ok)[0].data[:4] == b"glTF"
    with pytest.raises(BadInput, match="bake size"):
        svc.textured(ok, bake_size=100_000)


def test_an_unreadable_family_is_listed_and_answers_503_naming_the_permission(family, monkeypatch):
    """A family folder the server may not read stays in /v1/families with its health saying why,
    and its routes answer 503 (not a plain 500), while the others are served."""
    from fastapi.testclient import TestClient

    from workers.http import create_app

    root, _ = family
    shutil.copytree(root / "mug", root / "cup")
    real = FamilyStore.exists

    def exists(self, rel):
        if "cup" in self.path(rel).split("/"):
            raise PermissionError(errno.EACCES, "Permission denied", self.path(rel))
        return real(self, rel)

    monkeypatch.setattr(FamilyStore, "exists", exists)
    cat = Catalog(str(root), check_every=0)
    c = TestClient(create_app(lambda: cat))
    listed = c.get("/v1/families").json()
    assert listed["families"] == ["cup", "mug"] and listed["health"]["mug"] == "ok" and "Permission" in listed["health"]["cup"]
    r = c.get("/v1/families/cup")
    assert r.status_code == 503 and "Permission" in r.json()["error"]
    assert c.get("/v1/families/mug").status_code == 200


def test_the_command_line_takes_what_http_takes_and_a_refused_build_leaves_out_as_it_was(family, tmp_path, capsys):
    """One set of bounds on both sides: a 201-character prompt, 257 group prompts, a 1.5 MB
    --group-prompts file are refused by `look add` before any work (exit 2, the family unchanged)
    as by POST .../looks (422); a build refused for its --params-spec (bounds of a parameter the
    model lacks) leaves --out as it was: a new folder not made, an empty one still empty (it left
    family.json and lock files, and the corrected build was then refused)."""
    import json

    from fastapi.testclient import TestClient

    from proctex.cli import main
    from workers.http import create_app

    root, _ = family
    fam = root / "mug"
    before = tree(fam)
    many = tmp_path / "many.json"
    many.write_text(json.dumps({str(k): "oak" for k in range(257)}))
    huge = tmp_path / "huge.json"
    huge.write_text(json.dumps({str(k): "oak" for k in range(100_000)}))
    for flags, message in (
        (["--prompt", "x" * 201], "at most 200"),
        (["--prompt", "oak", "--group-prompts", str(many)], "at most 256"),
        (["--prompt", "oak", "--group-prompts", str(huge)], "at most 262144"),
    ):
        assert main(["look", "add", str(fam), "big", *flags]) == 2, flags
        assert message in capsys.readouterr().err, flags
        assert tree(fam) == before
    c = TestClient(create_app(lambda: Catalog(str(root), check_every=0), edit_token="tok"))
    for body in ({"name": "big", "prompt": "x" * 201}, {"name": "big", "prompt": "oak", "group_prompts": {str(k): "oak" for k in range(257)}}):
        r = c.post("/v1/families/mug/looks", json=body, headers=TOKEN)
        assert r.status_code == 422 and "200 characters" in r.json()["error"], r.text
    assert main(["look", "add", str(fam), "fine", "--prompt", "x" * 200]) == 0  # the bound itself is taken
    spec = tmp_path / "spec.json"
    spec.write_text(json.dumps({"nope": [0, 1]}))
    empty = tmp_path / "empty"
    empty.mkdir()
    for out in (tmp_path / "new", empty):
        argv = ["build", "--model", "mug", "--prompt", "red", "--out", str(out), "--n-train", "2", "--n-test", "0", "--stages", "sample"]
        assert main([*argv, "--params-spec", str(spec)]) == 2
        assert "unknown parameters: nope" in capsys.readouterr().err
        assert (not out.exists()) if out.name == "new" else list(out.iterdir()) == []
        assert main(argv) == 0  # the corrected build is not refused as "built with another config"


@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o027, 0o640)])
def test_files_the_tool_writes_honour_the_umask(family, tmp_path, umask, mode):
    """A transfer's GLB and preview and a look's store files get 0666 less the umask (0644 by
    default), as any new file does: they were 0600 (the atomic write's private temporary kept its
    mode), so another user or a web server could not read what the tool made."""
    root, _ = family
    fam = root / "mug"
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    code = "import os, sys\nos.umask(int(sys.argv[1], 8))\nfrom proctex.cli import main\nsys.exit(main(sys.argv[2:]))\n"
    out = tmp_path / "out"
    out.mkdir()
    for argv in (["transfer", str(fam), "--params", "{}", "--out", str(out / "x.glb"), "--preview", str(out / "x.png")], ["look", "add", str(fam), "modes", "--prompt", "oak"]):
        done = subprocess.run([sys.executable, "-c", code, oct(umask), *argv], env=env, capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr[-2000:]
    made = [out / "x.glb", out / "x.png", *sorted(p for p in (fam / "looks" / "modes").rglob("*") if p.is_file())]
    assert len(made) > 4
    assert {str(p.relative_to(tmp_path if p.is_relative_to(tmp_path) else root)): oct(p.stat().st_mode & 0o777) for p in made} == {
        str(p.relative_to(tmp_path if p.is_relative_to(tmp_path) else root)): oct(mode) for p in made
    }
