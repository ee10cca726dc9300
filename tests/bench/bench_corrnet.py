"""Benchmark: ProcCorrNet trained on cage correspondences, evaluated on held-out shapes.

Data: for each model, shapes are drawn with ``space.sample(n, seed, method="lhs")`` (the template is
the model's default setting); every matched, non-degenerate group pair is solved by the cage solver
(:func:`proctex.correspond.dense.correspond_shapes`) and turned into a training pair ``src`` (shape part's
normalised frame) / ``dst`` (template part's normalised frame). The real sofa samples
(``--sofa-data``, no ground truth) use their train split for training and the inference split for
testing. Pairs are cached in ``out/`` (``.npz``) so reruns only train.

Per template group a network is trained on the train shapes (a few of them held out for early
stopping) and evaluated on the test shapes: pseudo-ground-truth error (network vs cage, docs/results.md)
and, on built-in models, the ground-truth error of the network's prediction projected onto the
template surface next to the cage solver's own ground-truth error on the same shapes.

    python tests/bench/bench_corrnet.py --models mug,table,chair --out out/bench_corrnet.json
    python tests/bench/bench_corrnet.py --models sofa_data --out out/bench_corrnet_sofa.json
    python tests/bench/bench_corrnet.py --models chair --data-only          # just build the cache
    python tests/bench/bench_corrnet.py --models chair --sweep lr=3e-4,1e-3,3e-3 --iterations 1500
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root (tests.data)
from tests.data import SOFA  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
SOFA_DIR = SOFA


# --------------------------------------------------------------------------------------------- data
def _template_and_shapes(name: str, n_train: int, n_test: int, seed: int, sofa_dir: Path):
    """``(template Shape, [(shape id, split, loader)])``; loaders are callables returning a Shape."""
    if name == "sofa_data":
        from proctex.sources.files import FolderSource

        src = FolderSource(sofa_dir)
        template = src.load(src.template_index())
        train = src.indices("train")[:n_train]
        test = src.indices("test")[:n_test]
        items = [(src.samples[i].id, "train", (lambda i=i: src.load(i))) for i in train]
        items += [(src.samples[i].id, "test", (lambda i=i: src.load(i))) for i in test]
        return template, items
    from proctex.models import get_model

    model = get_model(name)
    params = model.space.sample(n_train + n_test, seed=seed, method="lhs")
    items = [(f"s{k}", "train" if k < n_train else "test", (lambda p=p: model.generate(p))) for k, p in enumerate(params)]
    return model.generate(), items


def build_pairs(name: str, n_train: int, n_test: int, points: int, seed: int, sofa_dir: Path, quiet: bool = False) -> dict:
    """Cage pairs of one model as a dict of stacked arrays (see :func:`load_or_build`)."""
    import numpy as np

    from proctex.correspond.dense import correspond_shapes
    from proctex.geometry.parts import analyse, part_mesh
    from proctex.geometry.surface import interpolate, normalised_frame

    template, items = _template_and_shapes(name, n_train, n_test, seed, sofa_dir)
    tg = analyse(template)
    rows: dict[str, list] = {k: [] for k in ("src", "dst", "src_can", "shape", "split", "group", "template_part", "cage_gt", "cage_seconds", "src_frame")}
    t0 = time.perf_counter()
    for k, (sid, split, load) in enumerate(items):
        shape = load()
        sg = analyse(shape)
        res = correspond_shapes(shape, template, method="cage", n_points=points, seed=seed + k, grouping=sg, template_grouping=tg)
        for g in res.groups:
            r = g.result
            sv, sf = part_mesh(shape, sg.parts[g.shape_part])
            tv, tf = part_mesh(template, tg.parts[g.template_part])
            sc, sr = normalised_frame(sv[np.unique(sf)])
            tc, tr = normalised_frame(tv[np.unique(tf)])
            rows["src"].append(((r.source_points - sc) / sr).astype(np.float32))
            rows["dst"].append(((r.points - tc) / tr).astype(np.float32))
            if shape.canonical is not None:
                rows["src_can"].append(interpolate(shape.canonical[sg.parts[g.shape_part].vertices], sf, r.source_faces, r.source_bary))
            else:
                rows["src_can"].append(np.full((len(r.source_points), 3), np.nan))
            rows["shape"].append(sid)
            rows["split"].append(split)
            rows["group"].append(g.template_group)
            rows["template_part"].append(g.template_part)
            rows["cage_gt"].append([np.nan] * 3 if g.gt is None else [g.gt.mean, g.gt.p95, g.gt.max])
            rows["cage_seconds"].append(r.seconds)
            rows["src_frame"].append([*sc, sr])
        if not quiet:
            el = time.perf_counter() - t0
            print(f"[pairs {name}] {k + 1}/{len(items)} shapes, {len(rows['src'])} pairs, {el:.0f}s ({el / (k + 1):.1f}s/shape)", file=sys.stderr, flush=True)
    return {k: np.asarray(v) for k, v in rows.items()}


def load_or_build(name: str, n_train: int, n_test: int, points: int, seed: int, sofa_dir: Path, cache_dir: Path, quiet: bool = False) -> dict:
    """Pairs of one model from the cache ``cache_dir/corrnet_pairs_<name>_<train>_<test>_<points>_<seed>.npz``,
    building (and atomically writing) it when absent.

    Arrays (P pairs of n points): ``src, dst (P, n, 3) float32``; ``src_can (P, n, 3) float64``
    (NaN without ground truth); ``shape, split (P,) str``; ``group, template_part (P,) int``;
    ``cage_gt (P, 3)`` (mean, p95, max; NaN without ground truth); ``cage_seconds (P,)``;
    ``src_frame (P, 4)`` (centre, radius of the shape part).
    """
    import numpy as np

    path = cache_dir / f"corrnet_pairs_{name}_{n_train}_{n_test}_{points}_{seed}.npz"
    if path.is_file():
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    data = build_pairs(name, n_train, n_test, points, seed, sofa_dir, quiet)
    cache_dir.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, **data)
    os.replace(tmp, path)
    return data


# ---------------------------------------------------------------------------------------- evaluate
SUMMARY_KEYS = (
    "pgt_mean",
    "pgt_p95",
    "pgt_max_point",
    "pgt_max_shape_mean",
    "pgt_projected_mean",
    "identity_pgt_mean",
    "gt_mean",
    "gt_p95",
    "gt_max",
    "cage_gt_mean",
    "cage_gt_p95",
    "cage_gt_max",
    "train_seconds",
    "predict_ms",
    "predict_ms_bf16",
)


def _template_parts(name: str, sofa_dir: Path) -> tuple[object, object]:
    """The model's template shape and its grouping (regenerated; deterministic)."""
    from proctex.geometry.parts import analyse

    if name == "sofa_data":
        from proctex.sources.files import FolderSource

        src = FolderSource(sofa_dir)
        template = src.load(src.template_index())
    else:
        from proctex.models import get_model

        template = get_model(name).generate()
    return template, analyse(template)


def group_splits(data: dict, group: int, n_val: int) -> tuple[list, list, list, list]:
    """``(train pairs, val pairs, test pairs, test row indices)`` of one template group; the last
    ``n_val`` train shapes are held out for early stopping."""
    import numpy as np

    rows = np.flatnonzero(data["group"] == group)
    tr = [int(i) for i in rows if data["split"][i] == "train"]
    te = [int(i) for i in rows if data["split"][i] == "test"]
    n_val = min(n_val, max(len(tr) - 1, 0))
    val, tr = tr[len(tr) - n_val :], tr[: len(tr) - n_val]
    pair = lambda i: (data["src"][i], data["dst"][i])  # noqa: E731
    return [pair(i) for i in tr], [pair(i) for i in val], [pair(i) for i in te], te


def gt_errors(model, data: dict, rows: list[int], template, tgrouping, seed: int) -> dict:
    """Ground-truth error of the network's predictions projected onto the template part (as
    :func:`proctex.correspond.dense.correspond_shapes` computes it for the cage), next to the cage's,
    plus the pseudo-ground-truth error after projection."""
    import numpy as np

    from proctex.correspond.corrnet import predict
    from proctex.correspond.metrics import gt_correspondence_error
    from proctex.geometry.parts import part_mesh
    from proctex.geometry.surface import SurfaceIndex, normalised_frame

    tp = int(data["template_part"][rows[0]])
    tv, tf = part_mesh(template, tgrouping.parts[tp])
    tc, tr = normalised_frame(tv[np.unique(tf)])
    index = SurfaceIndex(tv, tf)
    has_gt = template.canonical is not None and not np.isnan(data["src_can"][rows[0]]).any()
    tcan = template.canonical[tgrouping.parts[tp].vertices] if has_gt else None
    net, proj = [], []
    for i in rows:
        src, dst = data["src"][i], data["dst"][i]
        pred = predict(model, src, src, seed=seed) * tr + tc
        hit = index.query(pred)
        proj.append(float(np.linalg.norm((hit.points - tc) / tr - dst, axis=1).mean()))
        if has_gt:
            net.append(gt_correspondence_error(data["src_can"][i], hit.points, hit.faces, tv, tf, tcan))
    out = {"pgt_projected_mean": float(np.mean(proj))}
    if has_gt:
        cage = data["cage_gt"][rows]
        out.update(
            gt_mean=float(np.mean([g.mean for g in net])),
            gt_p95=float(np.mean([g.p95 for g in net])),
            gt_max=float(np.max([g.max for g in net])),
            gt_flipped=float(np.mean([g.flipped for g in net])),
            cage_gt_mean=float(cage[:, 0].mean()),
            cage_gt_p95=float(cage[:, 1].mean()),
            cage_gt_max=float(cage[:, 2].max()),
        )
    return out


def predict_timing(model, src, template_vertices, repeats: int = 7) -> dict:
    """Median ms of :func:`proctex.correspond.corrnet.predict` on ``src`` samples plus a part's vertex count,
    in float32 and with bfloat16 autocast."""
    import numpy as np

    from proctex.correspond.corrnet import predict
    from proctex.geometry.surface import normalised_frame

    c, r = normalised_frame(template_vertices)
    query = np.concatenate([src, (template_vertices - c) / r])
    out = {"predict_queries": int(len(query))}
    for key, mode in (("predict_ms", "none"), ("predict_ms_bf16", "bfloat16")):
        predict(model, src, query, autocast=mode)
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            predict(model, src, query, autocast=mode)
            times.append(time.perf_counter() - t0)
        out[key] = 1000 * float(np.median(times))
    return out


def step_timing(config, repeats: int = 20) -> dict:
    """Median ms of one :func:`proctex.correspond.training.train_step` for ``config`` (random data)."""
    import numpy as np
    import torch

    from proctex.correspond.corrnet import build_model
    from proctex.correspond.training import sample_batch, train_step

    model = build_model(config)
    opt = torch.optim.Adam(model.parameters(), lr=config.lr)
    rng = np.random.default_rng(0)
    pairs = [(rng.uniform(-1, 1, (2000, 3)).astype(np.float32), rng.uniform(-1, 1, (2000, 3)).astype(np.float32)) for _ in range(4)]
    times = []
    for k in range(repeats + 3):
        ctx, qry, tgt = (torch.as_tensor(a) for a in sample_batch(pairs, config, rng))
        t0 = time.perf_counter()
        if config.query_mode == "context":
            train_step(model, opt, ctx, tgt, None, config.loss, config.autocast)
        else:
            train_step(model, opt, qry, tgt, ctx, config.loss, config.autocast)
        if k >= 3:
            times.append(time.perf_counter() - t0)
    return {"step_ms": 1000 * float(np.median(times))}


def run_group(name: str, data: dict, group: int, config, n_val: int, template, tgrouping, quiet: bool, timing: bool) -> dict:
    """Train one group's network and evaluate it on the group's test shapes."""
    import numpy as np

    from proctex.correspond.training import eval_step, train
    from proctex.geometry.parts import part_mesh

    tr, val, te, te_rows = group_splits(data, group, n_val)
    if not tr or not te:
        return {"model": name, "group": group, "skipped": f"{len(tr)} train / {len(te)} test pairs"}

    def show(e: dict) -> None:
        if not quiet:
            v = f"val {e['val_mean']:.4f}" if "val_mean" in e else ""
            print(f"  [{name} g{group}] it {e['iteration']:5d} train {e['train_error']:.4f} {v} lr {e['lr']:.2e} {e['seconds']:.0f}s", file=sys.stderr, flush=True)

    res = train(tr, val, config, on_eval=show)
    pgt = eval_step(res.model, te, seed=config.seed)
    identity = float(np.mean([np.linalg.norm(s - d, axis=1).mean() for s, d in te]))
    row = {
        "model": name,
        "group": group,
        "train_pairs": len(tr),
        "val_pairs": len(val),
        "test_pairs": len(te),
        "train_seconds": res.seconds,
        "iterations": res.iterations,
        "stopped_early": res.stopped_early,
        "best_iteration": res.best_val.get("iteration"),
        "val_mean": res.best_val.get("mean"),
        **{f"pgt_{k}": v for k, v in pgt.items() if k not in ("shapes", "points")},
        "identity_pgt_mean": identity,
        **gt_errors(res.model, data, te_rows, template, tgrouping, config.seed),
        "history": res.history,
    }
    if timing:
        tv, tf = part_mesh(template, tgrouping.parts[int(data["template_part"][te_rows[0]])])
        row.update(predict_timing(res.model, te[0][0], tv))
    if not quiet:
        gt = f" gt {row['gt_mean']:.4f} (cage {row['cage_gt_mean']:.4f})" if "gt_mean" in row else ""
        print(
            f"[{name} g{group}] pgt mean {row['pgt_mean']:.4f} max_pt {row['pgt_max_point']:.4f} max_shape {row['pgt_max_shape_mean']:.4f}"
            f" (identity {identity:.4f}){gt} train {res.seconds:.0f}s/{res.iterations} it",
            file=sys.stderr,
            flush=True,
        )
    return row


def _parse_value(text: str):
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return {"true": True, "false": False}.get(text.lower(), text)


def parse_settings(items: list[str]) -> dict:
    """``["lr=1e-3", "schedule=cosine"]`` -> ``{"lr": 0.001, "schedule": "cosine"}``."""
    out = {}
    for item in items:
        key, _, value = item.partition("=")
        out[key.strip()] = _parse_value(value.strip())
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", default="mug,table,chair", help="built-in model names and/or 'sofa_data'")
    ap.add_argument("--train-shapes", type=int, default=40, help="train shapes per built-in model (sofa_data: 50)")
    ap.add_argument("--test-shapes", type=int, default=10, help="test shapes per built-in model (sofa_data: 50)")
    ap.add_argument("--val-shapes", type=int, default=5, help="train shapes held out for early stopping")
    ap.add_argument("--points", type=int, default=2000, help="cage samples per pair")
    ap.add_argument("--groups", default="", help="only these template groups (comma list)")
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="CorrNetConfig settings")
    ap.add_argument("--sweep", nargs="*", default=[], metavar="KEY=V1,V2", help="vary one setting at a time around --set")
    ap.add_argument("--skip-base", action="store_true", help="with --sweep: run only the varied settings")
    ap.add_argument("--sofa-dir", default=str(SOFA_DIR))
    ap.add_argument("--cache", default=str(ROOT / "out"))
    ap.add_argument("--data-only", action="store_true")
    ap.add_argument("--step-timing", action="store_true", help="only time one train step per variant (random data)")
    ap.add_argument("--no-timing", action="store_true")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quiet", action="store_true")
    ap.add_argument("--out", default="")
    args = ap.parse_args(argv)

    os.environ.setdefault("OMP_NUM_THREADS", str(args.threads))
    import numpy as np
    import torch

    torch.set_num_threads(args.threads)
    sys.path.insert(0, str(ROOT))
    from proctex.correspond.corrnet import CorrNetConfig

    base = parse_settings(args.set)
    variants: list[tuple[str, dict]] = [] if (args.skip_base and args.sweep) else [("base", base)]
    for item in args.sweep:
        key, _, values = item.partition("=")
        variants += [(f"{key}={v}", {**base, key: _parse_value(v)}) for v in values.split(",")]
    rows: list[dict] = []
    if args.step_timing:
        for label, settings in variants:
            t = step_timing(CorrNetConfig(**settings).validate())
            print(json.dumps({"variant": label, **t}))
        return 0
    for name in [m for m in args.models.split(",") if m]:
        ntr, nte = (50, 50) if name == "sofa_data" else (args.train_shapes, args.test_shapes)
        data = load_or_build(name, ntr, nte, args.points, args.seed, Path(args.sofa_dir), Path(args.cache), args.quiet)
        if args.data_only:
            continue
        template, tgrouping = _template_parts(name, Path(args.sofa_dir))
        groups = sorted(set(int(g) for g in data["group"]))
        if args.groups:
            groups = [g for g in groups if str(g) in args.groups.split(",")]
        for label, settings in variants:
            config = CorrNetConfig(**{**settings, "seed": settings.get("seed", args.seed)}).validate()
            for g in groups:
                row = run_group(name, data, g, config, args.val_shapes, template, tgrouping, args.quiet, not args.no_timing)
                rows.append({"variant": label, "settings": settings, **row})

    summary = []
    for label, _ in variants:
        for name in [m for m in args.models.split(",") if m]:
            rs = [r for r in rows if r["variant"] == label and r["model"] == name and "pgt_mean" in r]
            if not rs:
                continue
            s = {"variant": label, "model": name, "groups": len(rs), "over_groups": {}}
            for k in SUMMARY_KEYS:
                vals = [r[k] for r in rs if r.get(k) is not None]
                if vals:
                    s["over_groups"][k] = {"mean": float(np.mean(vals)), "max": float(np.max(vals))}
            summary.append(s)
    out = {
        "benchmark": "corrnet",
        "settings": {**vars(args), "torch": torch.__version__, "time": time.strftime("%Y-%m-%d %H:%M:%S")},
        "summary": summary,
        "groups": rows,
    }
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(args.out).with_suffix(".tmp")
        tmp.write_text(json.dumps(out, indent=1, default=float))
        os.replace(tmp, args.out)
    for s in summary:
        print(json.dumps(s, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
