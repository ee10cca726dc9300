"""The teacher's confidence from neighbouring shapes (proctex.correspond.confidence) and the
weighted training it feeds."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from proctex.correspond.confidence import MIN_SCALE, confidence_weights, neighbour_disagreement
from proctex.correspond.corrnet import CorrNetConfig, build_model
from proctex.correspond.training import eval_step, sample_batch, train, train_step

TEMPLATE = np.array([1.0, 0.5, 0.3])  # the template part's half extents


def _box_pair(extent, rng, slipped=False, n=600):
    """A cage pair of a box part with half extents ``extent`` onto the template box: the exact
    box map, or with ``slipped`` a teacher that sent the top half (z > 0) to the mirror side in x."""
    p = rng.uniform(-1, 1, (n, 3))
    axis = rng.integers(0, 3, n)
    p[np.arange(n), axis] = np.sign(p[np.arange(n), axis])
    src = p * extent / np.max(extent)
    dst = src / np.abs(src).max(axis=0) * TEMPLATE
    if slipped:
        dst[dst[:, 2] > 0, 0] *= -1
    return src, dst


def _family(rng, slipped=(2, 5, 7)):
    extents = [np.array([1.0, 0.4 + 0.02 * i, 0.25 + 0.01 * i]) for i in range(10)]
    return [_box_pair(e, rng, i in slipped) for i, e in enumerate(extents)]


def test_disagreement_finds_the_slipped_region_of_the_slipped_pairs():
    """Pairs whose teacher slipped on their top half disagree with their neighbours there, by about
    the slip (twice |x|), and nowhere else; consistent pairs away from them agree to within the
    family's own variation; the weights follow."""
    pairs = _family(np.random.default_rng(0))
    d = neighbour_disagreement(pairs, k=3)
    w = confidence_weights(d)
    assert [x.shape for x in d] == [(len(s),) for s, _ in pairs] and [x.dtype for x in w] == [np.float32] * 10
    for i in (2, 5, 7):
        top = pairs[i][0][:, 2] > 0
        assert d[i][top].mean() > 0.8 and d[i][~top].mean() < 0.1
        assert w[i][top].mean() < 0.1 and w[i][~top].mean() > 0.5
    for i in (0, 1, 9):  # nearest shapes all consistent
        assert d[i].mean() < 0.1 and w[i].mean() > 0.5


@pytest.mark.slow  # over 15 s: not in make test's second pass (tests/suite.py)
def test_weighted_training_learns_the_consistent_teacher():
    """Three of ten teachers slipped on half their points: trained alike on every point, the
    network averages the slip into a 0.2 error on clean held-out shapes; weighted by the teacher's
    confidence it learns the box map (well under a tenth of that). The same data, seed and budget."""
    rng = np.random.default_rng(0)
    pairs = _family(rng)
    held_out = [_box_pair(np.array([1.0, 0.45, 0.28]), rng), _box_pair(np.array([1.0, 0.52, 0.3]), rng)]
    errors = {}
    for conf in ("none", "neighbours"):
        cfg = CorrNetConfig(iterations=250, local_hidden=32, feature_dim=64, decoder_hidden=64, context_points=128, query_points=64, eval_every=50, patience=0, confidence=conf)
        errors[conf] = eval_step(train(pairs, [], cfg).model, held_out)["mean"]
    assert errors["none"] > 0.1
    assert errors["neighbours"] < 0.1 * errors["none"]


def test_weights_are_relative_to_the_group_and_bounded_below_by_an_absolute_scale():
    d = [np.array([0.0, 1.0, 2.0]), np.array([1.0, 3.0])]
    w = confidence_weights(d)  # median 1: w = 1 / (1 + d^2)
    assert np.allclose(w[0], [1.0, 0.5, 0.2]) and np.allclose(w[1], [0.5, 0.1])
    assert np.allclose(confidence_weights(d, scale=2.0)[1], [0.8, 1 / (1 + 2.25)])
    exact = confidence_weights([np.full(4, 1e-9), np.full(4, 2e-9)])  # an exact family: noise is not a slip
    assert all((x > 0.999).all() for x in exact) and MIN_SCALE > 0
    assert confidence_weights([]) == []
    # one pair: nothing to compare with
    src = np.random.default_rng(0).uniform(-1, 1, (20, 3))
    assert (neighbour_disagreement([(src, src)])[0] == 0).all()


def test_bad_input_is_refused():
    src = np.zeros((5, 3))
    with pytest.raises(ValueError, match="pair"):
        neighbour_disagreement([src])
    with pytest.raises(ValueError, match="same non-empty"):
        neighbour_disagreement([(src, np.zeros((4, 3))), (src, src)])
    with pytest.raises(ValueError, match="finite"):
        neighbour_disagreement([(np.full((5, 3), np.nan), src), (src, src)])
    with pytest.raises(ValueError, match="k must"):
        neighbour_disagreement([(src, src), (src, src)], k=0)
    with pytest.raises(ValueError, match="scale"):
        confidence_weights([np.zeros(3)], scale=0.0)
    with pytest.raises(ValueError, match="non-negative"):
        confidence_weights([np.array([-1.0, 0.0])])
    for bad in ({"confidence": "cycles"}, {"confidence_neighbours": 0}, {"confidence_scale": float("inf")}, {"confidence_scale": True}):
        with pytest.raises(ValueError, match="confidence"):
            CorrNetConfig(**bad).validate()
    rng = np.random.default_rng(0)
    pairs = _family(rng)[:3]
    cfg = CorrNetConfig(iterations=2, local_hidden=8, feature_dim=8, decoder_hidden=8, context_points=16, query_points=8)
    with pytest.raises(ValueError, match="one \\(n,\\) array per train pair"):
        train(pairs, [], cfg, weights=[np.ones(600)] * 2)
    with pytest.raises(ValueError, match="not all zero"):
        train(pairs, [], cfg, weights=[np.zeros(600)] * 3)


def test_weighted_step_is_the_weighted_mean_and_ones_change_nothing():
    """The loss with weights of one is the unweighted loss (same step, same weights after); zero
    weights leave those targets out of the gradient entirely."""
    cfg = CorrNetConfig(local_hidden=8, feature_dim=8, decoder_hidden=8, context_points=16, query_points=8, shapes_per_batch=2)
    pairs = _family(np.random.default_rng(1))[:2]
    ctx, _, tgt, wq = sample_batch(pairs, cfg, np.random.default_rng(0))
    assert wq.shape == (2, 8) and (wq == 1).all()
    _, _, _, wq2 = sample_batch(pairs, cfg, np.random.default_rng(0), weights=[np.full(600, 0.25, np.float32)] * 2)
    assert (wq2 == 0.25).all()
    ctx, tgt = torch.as_tensor(ctx), torch.as_tensor(tgt)

    def stepped(weight, target):
        torch.manual_seed(0)
        m = build_model(cfg)
        opt = torch.optim.SGD(m.parameters(), lr=0.1)
        train_step(m, opt, ctx, target, None, weight=weight)
        return torch.cat([p.detach().flatten() for p in m.parameters()])

    assert torch.allclose(stepped(None, tgt), stepped(torch.ones(2, 8), tgt))
    w = torch.ones(2, 8)
    w[:, 4:] = 0
    moved = tgt.clone()
    moved[:, 4:] += 5.0  # targets with zero weight: anything at all
    assert torch.allclose(stepped(w, tgt), stepped(w, moved))
    with pytest.raises(ValueError, match="weight must be"):
        stepped(torch.ones(2, 7), tgt)


def test_parameter_features_and_neighbours_by_them():
    """Parameters become comparable columns (numbers scaled by their spread, booleans 0/1, other
    values one-hot); shapes without the same parameters give None (then neighbours are found by
    shape). Given features, the neighbours are the nearest in them, not in shape."""
    from proctex.correspond.confidence import param_features

    f = param_features([{"w": 1.0, "legs": 3, "apron": True, "top": "round"}, {"w": 3.0, "legs": 3, "apron": False, "top": "square"}, {"w": 2.0, "legs": 3, "apron": True, "top": "round"}])
    assert f.shape == (3, 4)  # w, apron, top one-hot (2); legs is constant: dropped
    assert np.allclose(f.std(axis=0), 1.0) and np.allclose(f.mean(axis=0), 0.0)
    assert param_features([{"w": 1.0}, {"h": 1.0}]) is None
    assert param_features([{}, {}]) is None and param_features([]) is None
    assert param_features([{"w": float("nan")}, {"w": 1.0}]) is None
    pairs = _family(np.random.default_rng(0), slipped=(0, 1, 2, 3))
    top = pairs[0][0][:, 2] > 0
    by_shape = neighbour_disagreement(pairs, k=3)
    assert by_shape[0][top].mean() < 0.1  # by shape its nearest are pairs 1-3, slipped the same way
    feats = np.array([[5.05], [0.1], [0.2], [0.3], [5.0], [5.1], [5.2], [5.3], [5.4], [5.5]])
    by_params = neighbour_disagreement(pairs, k=3, features=feats)
    assert by_params[0][top].mean() > 0.8  # by these parameters its nearest are clean pairs 4-6
    assert by_params[1][top].mean() < 0.1  # and pair 1's are 0, 2, 3
    with pytest.raises(ValueError, match="features"):
        neighbour_disagreement(pairs, features=feats[:5])
