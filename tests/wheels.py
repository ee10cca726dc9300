"""Building this tree's wheel for tests (tests/test_wheel.py, tests/test_cluster.py) without writing
into the tree: the packages, pyproject, README and LICENSE are copied to a scratch folder first."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
STUDIO_INDEX = ROOT / "workers" / "studio" / "dist" / "index.html"


def clean_env() -> dict[str, str]:
    """This process's environment without what would import this tree instead of an installed copy."""
    return {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}


def build_wheel(scratch: Path, out: Path) -> Path:
    """Build ``proctex-VERSION-py3-none-any.whl`` into ``out`` from a copy of the tree in ``scratch``
    (no build isolation: setuptools is this environment's). Returns the wheel's path."""
    ignore = shutil.ignore_patterns("__pycache__", "node_modules", "*.pyc")
    for name in ("proctex", "workers", "workflows"):
        shutil.copytree(ROOT / name, scratch / name, ignore=ignore)
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy2(ROOT / name, scratch / name)
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--no-build-isolation", str(scratch), "-w", str(out)], check=True, capture_output=True, text=True, env=clean_env(), timeout=600
    )
    (whl,) = out.glob("proctex-*.whl")
    return whl
