"""Loading a built family for transfer (``FamilyService``): the median load of ``--repeats``, then
transfers of the family's own unseen shapes as uploads (its first ``--meshes`` stored test meshes):
their median time and one digest of every GLB answered (equal digests before and after a change:
the same answers, byte for byte).

    .venv/bin/python tests/bench/bench_family_load.py --family out/demo/families/sofa

Runs on older checkouts too (``PYTHONPATH=<checkout>``: the layout before issue 33).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import statistics
import time


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--family", required=True, help="a built family's store (e.g. out/demo/families/sofa)")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--meshes", type=int, default=8)
    args = p.parse_args(argv)
    try:
        from proctex.serve.service import FamilyService
        from proctex.store.layout import FamilyStore
    except ImportError:  # the layout before issue 33
        from proctex.family.service import FamilyService
        from proctex.family.store import FamilyStore

    store = FamilyStore(args.family)
    loads = []
    for _ in range(args.repeats):
        t = time.perf_counter()
        svc = FamilyService(store)
        loads.append(time.perf_counter() - t)
    rows = [r for r in store.read_table("samples.parquet").to_pylist() if r["split"] == "test"][: args.meshes]
    times, digest = [], hashlib.sha256()
    for r in rows:
        shape = svc.shape_from_mesh(store.read_bytes(r["mesh"]), "mesh.obj")
        t = time.perf_counter()
        answer, _ = svc.textured(shape)
        times.append(time.perf_counter() - t)
        digest.update(answer.data)
    print(
        json.dumps(
            {
                "family": args.family,
                "load_ms": round(1000 * statistics.median(loads)),
                "meshes": len(rows),
                "transfer_ms": round(1000 * statistics.median(times), 1) if times else None,
                "glb_digest": digest.hexdigest()[:16],
            }
        )
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
