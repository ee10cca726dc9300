"""Loading a built family for transfer (``FamilyService``): the median load of ``--repeats``, then
the first transfer (which decodes the template textures it reads) and a second one.

    .venv/bin/python tests/bench/bench_family_load.py --family out/demo/families/sofa
"""

from __future__ import annotations

import argparse
import statistics
import time


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--family", required=True, help="a built family's store (e.g. out/demo/families/sofa)")
    p.add_argument("--repeats", type=int, default=7)
    args = p.parse_args(argv)
    from proctex.serve.service import FamilyService
    from proctex.store.layout import FamilyStore

    FamilyService(FamilyStore(args.family))  # imports and caches warm
    loads = []
    for _ in range(args.repeats):
        t = time.perf_counter()
        FamilyService(FamilyStore(args.family))
        loads.append(time.perf_counter() - t)
    svc = FamilyService(FamilyStore(args.family))
    firsts = []
    for _ in range(2):
        t = time.perf_counter()
        svc.textured(svc.shape_from_params({}) if svc.model is not None else None)
        firsts.append(time.perf_counter() - t)
    print(f"load median {1000 * statistics.median(loads):.1f} ms ({args.repeats} loads); "
          f"first transfer {1000 * firsts[0]:.1f} ms, second {1000 * firsts[1]:.1f} ms")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
