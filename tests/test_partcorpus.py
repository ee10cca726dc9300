"""The part-word benchmark's corpus and scoring (tests/bench/partcorpus.py, bench_partwords.py):
the objects are deterministic and fully labelled, the splits are disjoint, and the score can both
pass and fail: an oracle that paints each group with its own clause scores 1, one that gives every
group the next clause scores 0."""

from __future__ import annotations

import numpy as np
import pytest

from proctex.geometry.parts import analyse
from tests.bench import bench_partwords as B
from tests.bench import partcorpus as C


def test_objects_are_deterministic_labelled_and_span_every_kind():
    a, b = C.make_object(7), C.make_object(7)
    assert np.array_equal(a.shape.vertices, b.shape.vertices) and np.array_equal(a.shape.faces, b.shape.faces)
    kinds = set()
    for s in range(60):
        o = C.make_object(s)
        kinds.add(o.kind)
        assert set(o.shape.label_names) <= set(C.FORMS), o.shape.label_names  # every role has the forms users write
        assert o.shape.labels is not None and len(o.shape.labels) == len(o.shape.vertices)
        bare = C.unlabelled(o.shape)
        assert bare.labels is None and bare.label_names == () and bare.canonical is None
        assert np.isfinite(bare.vertices).all()
    assert kinds == set(C.KINDS)


def test_the_splits_are_disjoint_and_bad_seeds_are_refused():
    dev, held = C.seeds("development"), C.seeds("held_out")
    assert len(dev) >= 200 and len(held) >= 200 and not set(dev) & set(held)
    with pytest.raises(ValueError, match="split"):
        C.seeds("tuning")
    for bad in (-1, 1.5, True, "3"):
        with pytest.raises(ValueError, match="seed"):
            C.make_object(bad)


def _oracle(shift: int):
    def texts(case, shape, grouping):
        truth = B.group_truth(case.obj.shape, grouping)
        words = [w for w, _, _ in case.clauses]
        out = {}
        for gid, t in truth.items():
            out[gid] = f"{case.clauses[(words.index(t) + shift) % len(words)][2]}" if t in words else None
        return out

    return texts


def test_the_score_passes_an_oracle_and_fails_a_shifted_one():
    good, bad = B.Tally(), B.Tally()
    for s in C.seeds("development")[:12]:
        obj = C.make_object(s)
        case = B.compose(obj, np.random.default_rng(s))
        assert 2 <= len(case.clauses) <= 4 and all(f.split()[-1] in case.prompt for _, f, _ in case.clauses)
        cols = [B.colour_of(m) for _, _, m in case.clauses]
        assert min(B.delta_e(x, y) for i, x in enumerate(cols) for y in cols[i + 1 :]) >= B.MIN_DE
        shape = C.unlabelled(obj.shape)
        grouping = analyse(shape)
        truth = B.group_truth(obj.shape, grouping)
        good.add(case, truth, B.taken(case, _oracle(0)(case, shape, grouping)))
        bad.add(case, truth, B.taken(case, _oracle(1)(case, shape, grouping)))
    assert good.passed == good.prompts == 12 and good.summary()["precision"] == 1.0 and good.summary()["recall"] == 1.0
    assert bad.passed == 0 and bad.summary()["recall"] == 0.0 and bad.summary()["precision"] == 0.0


def test_the_readme_pictures_are_made_by_their_command(tmp_path):
    """``python tests/bench/partword_pictures.py`` paints and draws a kind's object under 150 KB."""
    from PIL import Image

    from tests.bench import partword_pictures as pics

    assert pics.main(["--out", str(tmp_path), "--kinds", "tools"]) == 0
    path = tmp_path / "partwords_tools.png"
    assert path.stat().st_size <= pics.MAX_BYTES
    image = np.asarray(Image.open(path).convert("RGB")).astype(int)
    assert image.shape[0] > image.shape[1] and (np.abs(image - 255).sum(-1) > 60).mean() > 0.02  # something painted
    with pytest.raises(SystemExit, match="unknown kinds"):
        pics.main(["--out", str(tmp_path), "--kinds", "spaceships"])
