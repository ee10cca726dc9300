"""The linter (ruff, configured in pyproject.toml) finds no error in the project's Python (syntax,
undefined and unused names), and reads every package folder, ``proctex/build`` among them: the
config gives its exclude list whole, so no release's default exclude of folders named ``build``
can drop the build package (ruff 0.17 reads it either way)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def ruff() -> str:
    found = shutil.which("ruff", path=str(Path(sys.executable).parent)) or shutil.which("ruff")
    if found is None:
        pytest.skip("ruff is not installed (make setup installs it)")
    return found


def test_the_linter_reads_the_build_package_and_finds_no_error():
    files = subprocess.run([ruff(), "check", "--show-files", "proctex", "workers", "workflows", "tests"], cwd=ROOT, capture_output=True, text=True, timeout=300).stdout
    listed = {Path(line.strip()).resolve() for line in files.splitlines() if line.strip().endswith(".py")}
    build = {p.resolve() for p in (ROOT / "proctex" / "build").glob("*.py")}
    assert build and build <= listed, sorted(str(p) for p in build - listed)
    assert not any("node_modules" in str(p) or ".venv" in str(p) for p in listed)
    done = subprocess.run([ruff(), "check", "--output-format", "concise", "proctex", "workers", "workflows", "tests"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-2000:]


FOLDERS = ("proctex", "workers", "workflows", "tests", "clients")


def test_every_python_file_is_formatted_the_build_package_included(tmp_path):
    """``ruff format --check`` (the formatter configured in pyproject.toml) finds every Python file of
    the project formatted (``make format`` formats them); with the project's config a file in a
    folder named ``build`` is read, not skipped (a misformatted one there is reported)."""
    done = subprocess.run([ruff(), "format", "--check", *FOLDERS], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-2000:]
    (tmp_path / "pyproject.toml").write_text((ROOT / "pyproject.toml").read_text())
    (tmp_path / "proctex" / "build").mkdir(parents=True)
    (tmp_path / "proctex" / "build" / "stage.py").write_text("x = {  'a':1 }\n")
    bad = subprocess.run([ruff(), "format", "--check", "proctex"], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert bad.returncode == 1 and "stage.py" in bad.stdout + bad.stderr, bad.stdout + bad.stderr
