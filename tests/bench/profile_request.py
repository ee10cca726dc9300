"""Where one mesh-upload request's time goes, in this process (no Ray): reading and welding the
mesh, the part-count check, the transfer, the GLB (textures embedded or linked; with the family's PBR
maps and, in the same run, without them), and the whole route through FastAPI's test client; medians
of repeated runs, plus the bytes per answer.

    .venv/bin/python tests/bench/profile_request.py --root out/fam --family sofa
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
import uuid
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))
from tests.data import SOFA  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", required=True)
    ap.add_argument("--family", required=True)
    ap.add_argument("--meshes", default=str(SOFA / "inference"), help="folder of .obj files to upload")
    ap.add_argument("--repeats", type=int, default=15)
    args = ap.parse_args(argv)

    from fastapi.testclient import TestClient

    from proctex.geometry.meshio import load_mesh_bytes
    from proctex.serve.catalog import Catalog
    from proctex.transfer.apply import glb, transfer
    from workers.http import create_app

    cat = Catalog(args.root)
    svc = cat.get(args.family)
    datas = [f.read_bytes() for f in sorted(Path(args.meshes).glob("*.obj"))]
    if not datas:
        raise SystemExit(f"no .obj files in {args.meshes}")
    client = TestClient(create_app(lambda: cat))

    def median_ms(fn) -> float:
        times = []
        for k in range(args.repeats):
            t0 = time.perf_counter()
            fn(k)
            times.append(time.perf_counter() - t0)
        return 1000 * statistics.median(times)

    shapes = [load_mesh_bytes(d, "upload.obj")[0] for d in datas]
    results = [transfer(s, svc.assets, svc.mapper, painter=svc.painter) for s in shapes]
    rows = {
        "reading and welding the mesh": median_ms(lambda k: load_mesh_bytes(datas[k % len(datas)], "upload.obj")),
        "part-count check": median_ms(lambda k: svc.check_shape(shapes[k % len(shapes)])),
        "transfer (segment, assign, map, UVs)": median_ms(lambda k: transfer(shapes[k % len(shapes)], svc.assets, svc.mapper, painter=svc.painter)),
        "GLB, textures embedded": median_ms(lambda k: glb(shapes[k % len(shapes)], results[k % len(shapes)], svc.assets, up=svc.up)),
        "GLB, textures linked": median_ms(lambda k: glb(shapes[k % len(shapes)], results[k % len(shapes)], svc.assets, up=svc.up, texture_uris=svc.texture_uris(), map_uris=svc.map_uris())),
    }
    if svc.assets.pbr_png is not None:  # the same GLBs without the maps: what the maps cost
        from dataclasses import replace

        plain = replace(svc.assets, pbr=None)
        rows["GLB, embedded, colour only"] = median_ms(lambda k: glb(shapes[k % len(shapes)], results[k % len(shapes)], plain, up=svc.up))
        rows["GLB, linked, colour only"] = median_ms(lambda k: glb(shapes[k % len(shapes)], results[k % len(shapes)], plain, up=svc.up, texture_uris=svc.texture_uris()))
        print("bytes per GLB, embedded: with maps", len(glb(shapes[0], results[0], svc.assets, up=svc.up)), "colour only", len(glb(shapes[0], results[0], plain, up=svc.up)))
    for mode in ("embedded", "linked"):
        sizes: list[int] = []

        def request(k: int) -> None:
            boundary = uuid.uuid4().hex
            body = (
                (f'--{boundary}\r\nContent-Disposition: form-data; name="mesh"; filename="m.obj"\r\nContent-Type: application/octet-stream\r\n\r\n').encode()
                + datas[k % len(datas)]
                + f"\r\n--{boundary}--\r\n".encode()
            )
            answer = client.post(f"/v1/families/{args.family}/transfer?textures={mode}", content=body, headers={"content-type": f"multipart/form-data; boundary={boundary}"})
            if answer.status_code != 200:
                raise SystemExit(answer.text[:500])
            sizes.append(len(answer.content))

        rows[f"the whole route, {mode}"] = median_ms(request)
        print(f"bytes per answer, {mode}: {int(statistics.median(sizes))}")
    for key, ms in rows.items():
        print(f"{key}: {ms:.1f} ms")
    print(f"faces (median): {int(statistics.median(s.n_faces for s in shapes))}, upload bytes (median): {int(statistics.median(len(d) for d in datas))}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
