"""Which part pairs the sweep teacher would take: tube-like on both sides and a change of winding.

For each built-in model (3 random shapes against the default, adaptive tessellation), the sofa
export (its first 20 train shapes against its template) and any built family folder given with
``--store`` (its first 16 stored sample meshes against the first), every matched group pair is
charted (:mod:`proctex.geometry.chart`) and counted: pairs, template parts long enough
(``aspect >= CageConfig.sweep_aspect``), tubes among them (``tubular``), and the pairs whose turns
differ by ``CageConfig.sweep_turns`` or more (the ones the sweep teacher may take, if it also fits
better than the cage).

    python tests/bench/sweep_pairs.py
    python tests/bench/sweep_pairs.py --models "" --store out/fam/chair2
"""

from __future__ import annotations

import argparse
import glob
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root (tests.data)
from tests.data import SOFA  # noqa: E402


def scan(name: str, template, shapes, aspect: float, turns: float) -> dict:
    from proctex.correspond.dense import choose_member
    from proctex.correspond.sweep import template_chart
    from proctex.geometry.chart import sweep_chart
    from proctex.geometry.matching import match_groups
    from proctex.geometry.parts import analyse, part_mesh
    from proctex.geometry.surface import normalised_frame

    tg = analyse(template)
    row = {"family": name, "pairs": 0, "long": 0, "tubes": 0, "sweep": 0}
    for s in shapes:
        sg = analyse(s)
        for a, b in match_groups(s, sg, template, tg, seed=0).pairs:
            ga, gb = sg.groups[a], tg.groups[b]
            if ga.degenerate or gb.degenerate:
                continue
            row["pairs"] += 1
            tv, tf = part_mesh(template, tg.parts[gb.representative])
            c, r = normalised_frame(tv[np.unique(tf)])
            ch = template_chart((tv - c) / r, tf)
            if ch is None or ch.aspect < aspect:
                continue
            row["long"] += 1
            if not ch.tubular:
                continue
            row["tubes"] += 1
            sv, sf = part_mesh(s, sg.parts[choose_member(s, sg, ga, template, tg, gb)])
            c2, r2 = normalised_frame(sv[np.unique(sf)])
            try:
                sc = sweep_chart((sv - c2) / r2, sf, reference=ch.reference)
            except ValueError:
                continue
            if sc.aspect >= aspect and sc.tubular and abs(sc.turns - ch.turns) >= turns:
                row["sweep"] += 1
    print(f"| {row['family']} | {row['pairs']} | {row['long']} | {row['tubes']} | {row['sweep']} |", flush=True)
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", default="mug,vase,desk,chair,stair,fork,table,mushroom,cake,pumpkin,shell,sofa")
    ap.add_argument("--sofa-dir", default=str(SOFA))
    ap.add_argument("--store", action="append", default=[], help="a built family folder (its meshes/*.obj)")
    args = ap.parse_args(argv)
    from proctex.correspond.cage import CageConfig
    from proctex.geometry.meshio import load_mesh
    from proctex.models import get_model
    from proctex.sources.files import FolderSource

    cfg = CageConfig()
    print("| family | pairs | template part long enough | tubes | pairs the sweep may take |\n|---|---|---|---|---|")
    for name in [m for m in args.models.split(",") if m]:
        model = get_model(name, tessellation="adaptive")
        scan(name, model.generate(), [model.generate(p) for p in model.space.sample(3, seed=17)], cfg.sweep_aspect, cfg.sweep_turns)
    if args.sofa_dir and Path(args.sofa_dir).is_dir():
        src = FolderSource(args.sofa_dir)
        scan("sofa (export)", src.load(src.template_index()), [src.load(i) for i in src.indices("train")[:20]], cfg.sweep_aspect, cfg.sweep_turns)
    for store in args.store:
        files = sorted(glob.glob(str(Path(store) / "meshes" / "*.obj")))
        if len(files) < 2:
            raise SystemExit(f"--store {store}: fewer than two meshes in meshes/")
        scan(Path(store).name, load_mesh(files[0])[0], [load_mesh(f)[0] for f in files[1:17]], cfg.sweep_aspect, cfg.sweep_turns)
    return 0


if __name__ == "__main__":
    sys.exit(main())
