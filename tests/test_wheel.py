"""The wheel (issue 55): built from a copy of the tree, it carries what the tool needs at run time
(the studio's bundle, the Blender server script, the licence, the entry point, the extras) and
installs into a fresh virtual environment where ``proctex`` runs from it, not from this tree.

``make test`` keeps it fast: the dependencies are this environment's (a path file names its
site-packages, whose own path files, this tree's editable install among them, are not read), and
the wheel goes in with ``--no-deps``. docs/packaging.md gives the clean install with every
dependency, done by hand.
"""

from __future__ import annotations

import json
import subprocess
import sys
import sysconfig
import tomllib
import zipfile
from email.parser import Parser
from pathlib import Path

import pytest

from tests.wheels import STUDIO_INDEX, build_wheel, clean_env

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
VERSION = PYPROJECT["project"]["version"]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    if not STUDIO_INDEX.is_file():
        pytest.skip("the studio is not bundled (no npm): `make studio` first")
    return build_wheel(tmp_path_factory.mktemp("src"), tmp_path_factory.mktemp("wheel"))


def test_the_wheel_carries_what_the_tool_needs_at_run_time(wheel):
    assert wheel.name == f"proctex-{VERSION}-py3-none-any.whl"
    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
        meta = Parser().parsestr(z.read(f"proctex-{VERSION}.dist-info/METADATA").decode())
        entry = z.read(f"proctex-{VERSION}.dist-info/entry_points.txt").decode()
    built = {f"workers/studio/dist/{p.name}" for p in STUDIO_INDEX.parent.iterdir() if p.is_file()}
    assert built and built <= names  # the studio's bundle, every file of it
    assert "proctex/sources/blender_server.py" in names and f"proctex-{VERSION}.dist-info/licenses/LICENSE" in names
    assert not any("node_modules" in n or n.startswith("tests/") or n.startswith("workers/studio/src") for n in names)
    assert "proctex = workflows.cli:main" in entry
    assert set(meta.get_all("Provides-Extra")) >= {"viz", "embree", "diffusion", "dev"}
    assert meta["Version"] == VERSION and meta["License-Expression"] == "MIT"


@pytest.mark.slow
def test_the_wheel_installs_into_a_fresh_environment_and_runs_from_it(wheel, tmp_path):
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    site = Path(
        subprocess.run([str(venv / "bin" / "python"), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], check=True, capture_output=True, text=True, env=clean_env()).stdout.strip()
    )
    (site / "proctex-deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")  # this environment's dependencies
    subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(venv / "bin" / "python"), "install", "--quiet", "--no-deps", "--no-index", str(wheel)], check=True, capture_output=True, text=True, timeout=300
    )
    run = lambda *a: subprocess.run(list(a), cwd=tmp_path, env=clean_env(), capture_output=True, text=True, timeout=300)  # noqa: E731
    r = run(str(venv / "bin" / "proctex"), "--version")
    assert r.returncode == 0 and r.stdout.strip() == f"proctex {VERSION}", r.stderr
    probe = (
        "import json, proctex, workers.http as h, proctex.sources.blender as b; "
        "print(json.dumps([proctex.__file__, str(h.STUDIO_DIST / 'index.html'), (h.STUDIO_DIST / 'index.html').is_file(), b.SERVER.is_file()]))"
    )
    r = run(str(venv / "bin" / "python"), "-c", probe)
    assert r.returncode == 0, r.stderr
    module, studio, studio_there, server_there = json.loads(r.stdout)
    assert Path(module).is_relative_to(venv) and Path(studio).is_relative_to(venv)  # the installed copy, not this tree
    assert studio_there and server_there
    r = run(str(venv / "bin" / "proctex"), "sample", "mug", "--n", "2", "--out", str(tmp_path / "mugs"), "--quiet")
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in (tmp_path / "mugs").iterdir() if p.suffix == ".obj") == ["0.obj", "1.obj"]
    r = run(str(venv / "bin" / "proctex"), "serve", "--help")  # the Ray layer's commands come with it
    assert r.returncode == 0 and "--replicas" in r.stdout
