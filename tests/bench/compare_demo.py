"""Compare two ``proctex demo`` output folders: the contact sheet pixel for pixel, the family's
template textures byte for byte and decoded, and every variant GLB read back (vertices, faces, UVs,
texture images). A refactor that must not change what the demo makes passes this.

    .venv/bin/python tests/bench/compare_demo.py BEFORE AFTER
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def image(path: Path) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(path).convert("RGBA"))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("before")
    p.add_argument("after")
    args = p.parse_args(argv)
    a, b = Path(args.before), Path(args.after)
    problems = []
    sa, sb = image(a / "contact_sheet.png"), image(b / "contact_sheet.png")
    print(f"contact sheet {sa.shape[1]}x{sa.shape[0]}: {'identical' if sa.shape == sb.shape and np.array_equal(sa, sb) else 'DIFFERENT'}")
    if not (sa.shape == sb.shape and np.array_equal(sa, sb)):
        problems.append("contact sheet")
    ta = sorted((a / "families/sofa/template").glob("group_*.png"))
    tb = sorted((b / "families/sofa/template").glob("group_*.png"))
    same = [x.name == y.name and np.array_equal(image(x), image(y)) for x, y in zip(ta, tb)]
    print(f"template textures: {sum(same)} of {len(ta)} identical (decoded){'' if len(ta) == len(tb) else ', counts differ'}")
    if len(ta) != len(tb) or not all(same):
        problems.append("template textures")
    import trimesh

    va = sorted((a / "variants").glob("*.glb"))
    vb = sorted((b / "variants").glob("*.glb"))
    ok = 0
    for x, y in zip(va, vb):
        sx = trimesh.load(x, file_type="glb", process=False)
        sy = trimesh.load(y, file_type="glb", process=False)
        gx, gy = list(sx.geometry.values()), list(sy.geometry.values())
        equal = len(gx) == len(gy)
        for mx, my in zip(gx, gy):
            equal &= np.array_equal(mx.vertices, my.vertices) and np.array_equal(mx.faces, my.faces)
            ux, uy = getattr(mx.visual, "uv", None), getattr(my.visual, "uv", None)
            equal &= (ux is None and uy is None) or (ux is not None and uy is not None and np.array_equal(ux, uy))
            ix = getattr(getattr(mx.visual, "material", None), "baseColorTexture", None)
            iy = getattr(getattr(my.visual, "material", None), "baseColorTexture", None)
            equal &= (ix is None and iy is None) or (ix is not None and iy is not None and np.array_equal(np.asarray(ix), np.asarray(iy)))
        ok += bool(equal)
    print(f"variant GLBs: {ok} of {len(va)} identical (vertices, faces, UVs, textures){'' if len(va) == len(vb) else ', counts differ'}")
    if ok != len(va) or len(va) != len(vb):
        problems.append("variants")
    print("identical" if not problems else "DIFFERENT: " + ", ".join(problems))
    return 0 if not problems else 1


if __name__ == "__main__":
    sys.exit(main())
