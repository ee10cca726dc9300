"""Pack the Blender add-on, in both forms Blender installs from disk:

    python clients/blender/build_zip.py OUT.zip               # legacy add-on (bl_info), any Blender >= 4.2
    python clients/blender/build_zip.py --extension OUT.zip   # extension (blender_manifest.toml), Blender >= 4.2

The legacy zip holds a folder ``proctex_blender/`` with the modules (Preferences > Add-ons > Install
from Disk); the extension zip holds the modules and ``blender_manifest.toml`` at its root, the layout
the extensions platform expects (Preferences > Get Extensions > Install from Disk, or ``blender
--command extension build`` / ``validate`` on the package folder). No compiled files in either."""

from __future__ import annotations

import sys
import zipfile
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent / "proctex_blender"
MANIFEST = "blender_manifest.toml"


def _modules() -> list[Path]:
    return [p for p in sorted(PACKAGE.rglob("*.py")) if "__pycache__" not in p.parts]


def build(out: str | Path) -> Path:
    """Write the legacy add-on zip (a package folder, no manifest) to ``out``; its path."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as zf:
        for path in _modules():
            zf.write(path, Path(PACKAGE.name) / path.relative_to(PACKAGE))
    return out


def build_extension(out: str | Path) -> Path:
    """Write the extension zip (modules and manifest at the root) to ``out``; its path."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.write(PACKAGE / MANIFEST, MANIFEST)
        for path in _modules():
            zf.write(path, path.relative_to(PACKAGE))
    return out


if __name__ == "__main__":
    args = sys.argv[1:]
    if args and args[0] == "--extension":
        print(build_extension(args[1] if len(args) > 1 else "out/proctex_blender_extension.zip"))
    else:
        print(build(args[0] if args else "out/proctex_blender.zip"))
