"""Part words against truth (issue 51): precision, recall and confusion per word and per kind.

For each object of the part corpus (:mod:`tests.bench.partcorpus`; shapes the resolver sees without
their labels) a prompt names 2 to 4 of its parts, each with a material of its own ("a bed with a
white linen mattress, a walnut headboard and black metal legs"; the forms users write, from
``partcorpus.FORMS``; colours at least 25 ΔE2000 apart). The resolver
(:func:`proctex.texture.painters.partwords.plan_parts`) gives every part group a text; a group *took*
a clause when its text's colour is nearer that clause's colour than any other clause's and within
``MATCH_DE`` of it. Truth: the role its parts were built with (the area-majority of its members).

- per word: precision (of the groups that took the word's clause, the share whose truth is that
  word, among groups whose truth the prompt names), recall (of the groups whose truth is the word,
  the share that took its clause), and the confusion (truth word -> the word whose clause it took,
  or "none");
- whole prompts: a prompt passes when every group whose truth the prompt names took its own clause;
- the same for the groups' mean painted colours (``painted``: the surface painter at 32 texels a side,
  a clause taken within ``PAINTED_DE`` ΔE2000 of its colour and nearer it than any other's);
- the same for a trivial baseline beside it: groups touching the floor take the clause of a word of
  what stands on the ground (legs, feet, wheels, base, stand, trunk, foot, pot), the largest group
  the first other clause, no other group any.

``python tests/bench/bench_partwords.py [--split development|held_out|builtin|blend|sofa|all] [--n N] [--out DIR]``
writes ``partwords.json`` and ``partwords.md`` (the tables) in DIR (default ``out/bench``).
"""

from __future__ import annotations

import sys
import argparse
import json
import time
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
from skimage.color import deltaE_ciede2000, rgb2lab

from proctex.geometry.parts import Grouping, analyse
from proctex.geometry.surface import triangle_areas
from proctex.texture.painters.partwords import plan_parts
from proctex.texture.painters.prompt import parse_prompt

try:
    from . import partcorpus as C
except ImportError:  # run as a script
    import partcorpus as C  # type: ignore[no-redef]

#: materials a prompt gives its clauses (each parsed to a distinct colour)
MATERIALS = (
    "red velvet",
    "black metal",
    "white linen",
    "walnut",
    "green glass",
    "blue fabric",
    "yellow plastic",
    "grey stone",
    "orange leather",
    "brass",
    "pink ceramic",
    "purple silk",
    "teal plastic",
)
MIN_DE = 25.0  # clause colours of one prompt at least this far apart (ΔE2000)
MATCH_DE = 12.0  # a group took a clause only within this of the clause's colour
#: painted: a group's mean painted colour took a clause within this of the clause's colour (the
#: colours of one prompt are at least 25 apart; a development run: own clause median 1.3, max 11.7)
PAINTED_DE = 15.0
GROUND = {"legs", "leg", "feet", "wheels", "tyres", "tires", "base", "plinth", "stand", "trunk", "foot", "pot", "planter"}


def lab(rgb) -> np.ndarray:
    return rgb2lab(np.clip(np.asarray(rgb, float), 0, 1).reshape(1, 1, 3))[0, 0]


def colour_of(text: str) -> np.ndarray:
    """The Lab colour a text paints with (its first base colour)."""
    return lab(parse_prompt(text).base_colors[0])


def delta_e(a: np.ndarray, b: np.ndarray) -> float:
    return float(deltaE_ciede2000(a.reshape(1, 1, 3), b.reshape(1, 1, 3))[0, 0])


@dataclass
class Case:
    """One object with one prompt: the clauses (truth word, form, material) and the prompt."""

    obj: C.CorpusObject
    clauses: list[tuple[str, str, str]]
    prompt: str


def distinct_materials(k: int, rng: np.random.Generator) -> list[str]:
    """``k`` materials of :data:`MATERIALS` in a random order, each at least :data:`MIN_DE` from the others."""
    mats: list[str] = []
    for m in rng.permutation(MATERIALS):
        if all(delta_e(colour_of(m), colour_of(x)) >= MIN_DE for x in mats):
            mats.append(str(m))
        if len(mats) == k:
            break
    return mats


def compose(obj: C.CorpusObject, rng: np.random.Generator) -> Case | None:
    """A prompt naming 2 to 4 of ``obj``'s truth words with distinct materials (None when it has fewer than two)."""
    roles = [r for r in obj.shape.label_names if r in C.FORMS]
    if len(roles) < 2:
        return None
    k = min(len(roles), int(rng.integers(2, 5)))
    chosen = [roles[i] for i in rng.permutation(len(roles))[:k]]
    mats = distinct_materials(k, rng)
    clauses = [(w, str(rng.choice(C.FORMS[w])), m) for w, m in zip(chosen, mats)]
    parts = [f"{m} {f}" for _, f, m in clauses]
    listed = parts[0] if len(parts) == 1 else ", ".join(parts[:-1]) + " and " + parts[-1]
    style = int(rng.integers(3))
    prompt = f"a {obj.noun} with {listed}" if style == 0 else f"{obj.noun}: {listed}" if style == 1 else listed
    return Case(obj, clauses, prompt)


def group_truth(shape_labelled, grouping: Grouping) -> dict[int, str]:
    """Group id -> the truth word of most of its area (labels of the labelled shape)."""
    areas = triangle_areas(shape_labelled.vertices, shape_labelled.faces)
    face_lab = shape_labelled.labels[shape_labelled.faces[:, 0]]
    out = {}
    for g in grouping.groups:
        if g.degenerate:
            continue
        votes: Counter = Counter()
        for m in g.members:
            f = grouping.segmentation.parts[m].faces
            for lab_i, a in zip(face_lab[f], areas[f]):
                votes[shape_labelled.label_names[lab_i]] += float(a)
        out[g.index] = votes.most_common(1)[0][0]
    return out


def taken(case: Case, texts: dict[int, str | None]) -> dict[int, str]:
    """Group id -> the truth word whose clause it took ("none": no clause's colour)."""
    return taken_colours(case, {gid: None if text is None else colour_of(text) for gid, text in texts.items()}, MATCH_DE)


def taken_colours(case: Case, colours: dict[int, np.ndarray | None], within: float) -> dict[int, str]:
    """Group id -> the truth word whose clause's colour its Lab colour is nearest, within ``within``
    ΔE2000 ("none" otherwise, or for None)."""
    cols = [colour_of(m) for _, _, m in case.clauses]
    out = {}
    for gid, c in colours.items():
        if c is None:
            out[gid] = "none"
            continue
        d = [delta_e(c, x) for x in cols]
        i = int(np.argmin(d))
        out[gid] = case.clauses[i][0] if d[i] <= within else "none"
    return out


def painted_colours(case: Case, shape, grouping: Grouping) -> dict[int, np.ndarray | None]:
    """Group id -> the Lab mean of what the surface painter painted it with (32 texels a side: the
    resolver's plan as the painter uses it, end to end)."""
    from proctex.texture.paint_loop import paint_template

    tex = paint_template(shape, grouping, case.prompt, size=32, up=case.obj.up, maps=False)
    out: dict[int, np.ndarray | None] = {}
    for g in grouping.groups:
        if g.degenerate:
            continue
        gt = tex.groups[g.index]
        out[g.index] = lab(gt.image[gt.painted].reshape(-1, 3).mean(axis=0)) if gt.painted.any() else None
    return out


def resolver_texts(case: Case, shape, grouping: Grouping) -> dict[int, str | None]:
    plan = plan_parts(case.prompt, shape.vertices, shape.faces, grouping, case.obj.up)
    return {g.index: plan.painted_text(g.index) for g in grouping.groups if not g.degenerate}


def baseline_texts(case: Case, shape, grouping: Grouping) -> dict[int, str | None]:
    """Floor-touching groups: the clause of a ground word; the largest group: the first other clause."""
    v, f = shape.vertices, shape.faces
    up = "xyz".index(case.obj.up)
    z0, z1 = v[:, up].min(), v[:, up].max()
    areas = triangle_areas(v, f)
    ground = next((m for w, form, m in case.clauses if form.split()[-1] in GROUND), None)
    other = next((m for w, form, m in case.clauses if form.split()[-1] not in GROUND), None)
    info = {}
    for g in grouping.groups:
        if g.degenerate:
            continue
        faces = np.concatenate([grouping.segmentation.parts[m].faces for m in g.members])
        zs = v[np.unique(f[faces])][:, up]
        info[g.index] = ((zs.min() - z0) / max(z1 - z0, 1e-12), float(areas[faces].sum()))
    largest = max(info, key=lambda k: info[k][1])
    out: dict[int, str | None] = {}
    for gid, (u_lo, _) in info.items():
        out[gid] = ground if (ground and u_lo <= 0.05) else other if gid == largest else None
    return out


@dataclass
class Tally:
    """Counts for one method: per word (tp, fp, fn), the confusion, passes of whole prompts."""

    tp: Counter = field(default_factory=Counter)
    fp: Counter = field(default_factory=Counter)
    fn: Counter = field(default_factory=Counter)
    confusion: dict[str, Counter] = field(default_factory=lambda: defaultdict(Counter))
    by_kind: dict[str, Counter] = field(default_factory=lambda: defaultdict(Counter))
    prompts: int = 0
    passed: int = 0

    def add(self, case: Case, truth: dict[int, str], took: dict[int, str]) -> bool:
        named = {w for w, _, _ in case.clauses}
        ok = True
        for gid, t in truth.items():
            p = took.get(gid, "none")
            if t in named:
                self.confusion[t][p] += 1
                if p == t:
                    self.tp[t] += 1
                    self.by_kind[case.obj.kind]["tp"] += 1
                else:
                    ok = False
                    self.fn[t] += 1
                    self.by_kind[case.obj.kind]["fn"] += 1
                    if p != "none":
                        self.fp[p] += 1
                        self.by_kind[case.obj.kind]["fp"] += 1
        self.prompts += 1
        self.passed += ok
        self.by_kind[case.obj.kind]["prompts"] += 1
        self.by_kind[case.obj.kind]["passed"] += ok
        return ok

    def word_rows(self) -> dict[str, dict[str, float]]:
        rows = {}
        for w in sorted(set(self.tp) | set(self.fn) | set(self.fp)):
            tp, fp, fn = self.tp[w], self.fp[w], self.fn[w]
            rows[w] = {"cases": tp + fn, "precision": tp / (tp + fp) if tp + fp else 0.0, "recall": tp / (tp + fn) if tp + fn else 0.0}
        return rows

    def summary(self) -> dict[str, Any]:
        tp, fp, fn = sum(self.tp.values()), sum(self.fp.values()), sum(self.fn.values())
        return {"prompts": self.prompts, "prompt_pass": self.passed / max(self.prompts, 1), "precision": tp / (tp + fp) if tp + fp else 0.0, "recall": tp / (tp + fn) if tp + fn else 0.0}


METHODS: dict[str, Callable] = {"resolver": resolver_texts, "baseline": baseline_texts}
#: the resolver measured on what the painter painted (mean colours), beside its texts
PAINTED = "painted"


#: The built-in models' own part labels -> truth words, written once (the models' labels are hidden
#: from the resolver; a label not listed names no word of the benchmark and is never in a prompt).
BUILTIN_TRUTH: dict[str, tuple[str, str, dict[str, str]]] = {
    "chair": ("furniture", "chair", {"seat": "seat", "leg": "legs", "post": "back", "slat": "back", "armrest": "arms"}),
    "desk": ("furniture", "desk", {"top": "top", "leg": "legs", "drawer": "drawers", "knob": "handles"}),
    "table": ("furniture", "table", {"top": "top", "leg": "legs", "apron": "apron"}),
    "sofa": ("furniture", "sofa", {"base": "base", "back": "back", "seat_cushion": "cushions", "armrest": "arms", "leg": "legs"}),
    "mug": ("tableware", "mug", {"body": "body", "handle": "handle"}),
    "mushroom": ("plants", "mushroom", {"cap": "cap", "stem": "stem", "small_cap": "cap", "small_stem": "stem"}),
}


#: The handed-out ``.blend`` files' node-tree part names -> truth words, written once (hidden from
#: the resolver): file -> (object, kind, noun, names). Needs bpy (``make blender``) and the files.
BLEND_TRUTH: dict[str, tuple[str, str, str, dict[str, str]]] = {
    "chair.blend": ("Cube", "furniture", "chair", {"Legs": "legs", "Seat": "seat", "Back": "back", "Arms": "arms"}),
    "table.blend": ("Cube", "furniture", "table", {"Top": "top", "Legs": "legs"}),
    "cabinet.blend": ("Cabinet", "furniture", "cabinet", {"Legs": "legs", "Board Back": "back", "Board Right": "sides", "Dividing Boards": "shelf", "Drawers": "drawers"}),
}
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root (tests.data)
from tests.data import BLENDS  # noqa: E402


def blend_objects(per_file: int = 6, seed: int = 0) -> list[C.CorpusObject]:
    """Each file of :data:`BLEND_TRUTH`: its file values and ``per_file - 1`` samples of its inputs
    (the bounds of its ``sp_*.json``), labelled by the node tree's part names."""
    from proctex.params import read_params_spec
    from proctex.sources.blender import BlenderModel

    out = []
    for file, (obj, kind, noun, names) in BLEND_TRUTH.items():
        spec = BLENDS / f"sp_{Path(file).stem}.json"
        read = read_params_spec(spec) if spec.is_file() else None
        model = BlenderModel(BLENDS / file, obj, bounds=read.bounds if read else {}, listed=sorted(read.kinds) if read else None)
        try:
            for i, params in enumerate([{}, *model.space.sample(per_file - 1, seed=seed)]):
                shape = model.generate(params)
                if shape.labels is not None:
                    out.append(C.CorpusObject(i, kind, noun, relabelled(shape, names)))
        finally:
            model.close()
    return out


SOFAS = BLENDS.parent / "procedural_sofa" / "train"


def sofa_objects(n: int = 10) -> list[C.CorpusObject]:
    """The first ``n`` sofa exports (y up, no part names), each connected part labelled once here by
    its box, measuring only: the mirrored pair at both ends of x the arms, the lowest thin slab the
    base, the part reaching the top the back, the other the seat."""
    import trimesh

    from proctex.geometry.parts import segment
    from proctex.geometry.shape import Shape

    out = []
    for i in range(n):
        path = SOFAS / f"{i}.obj"
        if not path.is_file():
            break
        mesh = trimesh.load(path, process=False)
        shape = Shape(np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64))
        v = shape.vertices
        parts = [p for p in segment(shape).parts if not p.degenerate]
        box = {p.index: (v[p.vertices].min(0), v[p.vertices].max(0)) for p in parts}
        lo, hi = v.min(0), v.max(0)
        role = {}
        for p in parts:
            b0, b1 = box[p.index]
            if b1[0] - b0[0] < 0.25 * (hi[0] - lo[0]) and (b0[0] <= lo[0] + 1e-6 or b1[0] >= hi[0] - 1e-6):
                role[p.index] = "arms"
            elif b1[1] - b0[1] < 0.1 * (hi[1] - lo[1]) and b0[1] <= lo[1] + 1e-6:
                role[p.index] = "base"
            elif b1[1] >= hi[1] - 1e-6:
                role[p.index] = "back"
            else:
                role[p.index] = "seat"
        names = ["", "arms", "base", "back", "seat"]
        labels = np.zeros(len(v), dtype=np.int32)
        for p in parts:
            labels[p.vertices] = names.index(role[p.index])
        out.append(C.CorpusObject(i, "furniture", "sofa", Shape(v, shape.faces, labels=labels, label_names=tuple(names)), up="y"))
    return out


def relabelled(shape, names: dict[str, str]):
    """``shape`` with its labels renamed to truth words (``names``; others kept, prefixed "other:")."""
    from proctex.geometry.shape import Shape

    new = [names.get(n, f"other:{n}") for n in shape.label_names]
    order = list(dict.fromkeys(new))
    labels = np.array([order.index(new[i]) for i in range(len(new))], dtype=np.int32)[shape.labels]
    return Shape(shape.vertices, shape.faces, labels=labels, label_names=tuple(order), source=shape.source)


def builtin_objects(per_model: int = 8, seed: int = 0) -> list[C.CorpusObject]:
    """The built-in models of :data:`BUILTIN_TRUTH`: each one's template and ``per_model - 1`` samples."""
    from proctex.models import get_model

    out = []
    for name, (kind, noun, names) in BUILTIN_TRUTH.items():
        m = get_model(name)
        for i, params in enumerate([None, *m.space.sample(per_model - 1, seed=seed)]):
            out.append(C.CorpusObject(i, kind, noun, relabelled(m.generate(params), names)))
    return out


def run(split: str, n: int | None = None, seed: int = 0) -> dict[str, Any]:
    """Every method on the first ``n`` objects of ``split`` ("development", "held_out", or
    "builtin": the built-in models' shapes, :data:`BUILTIN_TRUTH`; "blend": the handed-out files,
    :data:`BLEND_TRUTH`; "sofa": the sofa exports, :func:`sofa_objects`); the tallies and the failed prompts."""
    tallies = {m: Tally() for m in [*METHODS, PAINTED]}
    failures = []
    objs = builtin_objects() if split == "builtin" else blend_objects() if split == "blend" else sofa_objects() if split == "sofa" else [C.make_object(s) for s in C.seeds(split)]
    for k, obj in enumerate(objs[:n]):
        s = k if split in ("builtin", "blend", "sofa") else obj.seed
        case = compose(obj, np.random.default_rng([seed, s]))
        if case is None:
            continue
        shape = C.unlabelled(obj.shape)
        grouping = analyse(shape)
        truth = group_truth(obj.shape, grouping)
        for name in tallies:
            took = taken_colours(case, painted_colours(case, shape, grouping), PAINTED_DE) if name == PAINTED else taken(case, METHODS[name](case, shape, grouping))
            if not tallies[name].add(case, truth, took) and name == "resolver":
                failures.append({"seed": s, "noun": obj.noun, "prompt": case.prompt, "truth": {str(k): v for k, v in truth.items()}, "took": {str(k): v for k, v in took.items()}})
    return {"tallies": tallies, "failures": failures}


def table(tallies: dict[str, Tally]) -> str:
    words = sorted(set().union(*(t.word_rows() for t in tallies.values())))
    head = "| word | cases | " + " | ".join(f"{m} P | {m} R" for m in tallies) + " |"
    lines = [head, "|" + "---|" * (2 + 2 * len(tallies))]
    for w in words:
        rows = [t.word_rows().get(w, {"cases": 0, "precision": 0.0, "recall": 0.0}) for t in tallies.values()]
        lines.append(f"| {w} | {rows[0]['cases']} | " + " | ".join(f"{r['precision']:.2f} | {r['recall']:.2f}" for r in rows) + " |")
    for m, t in tallies.items():
        s = t.summary()
        lines.append(f"\n{m}: {s['prompts']} prompts, whole-prompt pass {s['prompt_pass']:.1%}, precision {s['precision']:.2f}, recall {s['recall']:.2f}")
    return "\n".join(lines)


def kind_table(tallies: dict[str, Tally]) -> str:
    kinds = sorted(set().union(*(t.by_kind for t in tallies.values())))
    lines = ["| kind | prompts | " + " | ".join(f"{m} pass | {m} R" for m in tallies) + " |", "|" + "---|" * (2 + 2 * len(tallies))]
    for k in kinds:
        cells = []
        for t in tallies.values():
            c = t.by_kind[k]
            cells.append(f"{c['passed'] / max(c['prompts'], 1):.0%} | {c['tp'] / max(c['tp'] + c['fn'], 1):.2f}")
        lines.append(f"| {k} | {next(iter(tallies.values())).by_kind[k]['prompts']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--split", default="development", choices=("development", "held_out", "builtin", "blend", "sofa", "all"))
    ap.add_argument("--n", type=int, default=None, help="the first N objects of each split (default all)")
    ap.add_argument("--out", default="out/bench")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    splits = ("development", "held_out", "builtin", "blend", "sofa") if args.split == "all" else (args.split,)
    report: dict[str, Any] = {}
    md = []
    for split in splits:
        t0 = time.perf_counter()
        res = run(split, args.n)
        tallies = res["tallies"]
        report[split] = {
            "summary": {m: t.summary() for m, t in tallies.items()},
            "words": {m: t.word_rows() for m, t in tallies.items()},
            "confusion": {m: {w: dict(c) for w, c in t.confusion.items()} for m, t in tallies.items()},
            "kinds": {m: {k: dict(c) for k, c in t.by_kind.items()} for m, t in tallies.items()},
            "failures": res["failures"],
            "seconds": time.perf_counter() - t0,
        }
        md += [f"## {split}", "", table(tallies), "", kind_table(tallies), ""]
        print(f"{split}: " + "; ".join(f"{m} pass {t.summary()['prompt_pass']:.1%} P {t.summary()['precision']:.2f} R {t.summary()['recall']:.2f}" for m, t in tallies.items()))
    (out / "partwords.json").write_text(json.dumps(report, indent=1))
    (out / "partwords.md").write_text("\n".join(md))
    print(f"wrote {out / 'partwords.md'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
