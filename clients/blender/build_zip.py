"""Pack the Blender add-on: ``python clients/blender/build_zip.py OUT.zip`` writes a zip that
Blender installs from Preferences > Add-ons > Install from Disk (a folder ``proctex_blender/`` with
its modules; no compiled files)."""

from __future__ import annotations

import sys
import zipfile
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent / "proctex_blender"


def build(out: str | Path) -> Path:
    """Write the add-on zip to ``out`` and return its path."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as zf:
        for path in sorted(PACKAGE.rglob("*.py")):
            if "__pycache__" not in path.parts:
                zf.write(path, Path(PACKAGE.name) / path.relative_to(PACKAGE))
    return out


if __name__ == "__main__":
    print(build(sys.argv[1] if len(sys.argv) > 1 else "out/proctex_blender.zip"))
