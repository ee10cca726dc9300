"""ProcCorrNet's training: batches of paired points, the learning-rate schedule, train and eval
steps, and :func:`train` with early stopping (:class:`TrainResult`)."""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
import torch

from .corrnet import (
    LOSSES,
    MIN_EXTENT,
    CorrNetConfig,
    Pair,
    ProcCorrNet,
    _autocast,
    _model_spec,
    build_model,
    check_pairs,
    resolve_autocast,
    predict,
    sample_indices,
    zero_residual,
)
from proctex.torch_kernels import resolve_vml

resolve_vml()  # MKL's kernels chosen on one thread (see proctex.torch_kernels)


def sample_batch(
    pairs: Sequence[Pair],
    config: CorrNetConfig,
    rng: np.random.Generator,
    size: int | None = None,
    weights: Sequence[np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One training batch: ``(context (B, N, 3), query (B, Q, 3), target (B, Q, 3), weight (B, Q))``
    float32.

    ``B = size or shapes_per_batch`` pairs drawn with replacement; per pair ``N = context_points``
    context samples and ``Q = query_points`` queries (the first Q context points, or an independent
    sample); ``weight``: the queries' entries of ``weights`` (per pair ``(n,)``), ones without.
    """
    B, N, Q = size or config.shapes_per_batch, config.context_points, config.query_points
    ctx, qry, tgt = np.empty((B, N, 3), np.float32), np.empty((B, Q, 3), np.float32), np.empty((B, Q, 3), np.float32)
    wq = np.ones((B, Q), np.float32)
    for b, j in enumerate(rng.integers(0, len(pairs), size=B)):
        src, dst = pairs[j]
        ci = sample_indices(len(src), N, rng)
        qi = ci[:Q] if config.query_mode == "context" else sample_indices(len(src), Q, rng)
        ctx[b], qry[b], tgt[b] = src[ci], src[qi], dst[qi]
        if weights is not None:
            wq[b] = weights[j][qi]
    return ctx, qry, tgt, wq


def learning_rate(config: CorrNetConfig, step: int) -> float:
    """Learning rate of ``step`` (0-based) under the config's schedule."""
    t = min(step / max(config.iterations, 1), 1.0)
    if config.schedule == "cosine":
        return config.lr * (config.lr_final + (1 - config.lr_final) * 0.5 * (1 + math.cos(math.pi * t)))
    if config.schedule == "step":
        return config.lr * (0.1 ** ((t >= 0.6) + (t >= 0.85)))
    return config.lr


def step_error(
    model: ProcCorrNet,
    optimiser: torch.optim.Optimizer,
    src: torch.Tensor,
    dst: torch.Tensor,
    context: torch.Tensor | None = None,
    loss: str = "mse",
    autocast: str = "none",
    grad_hook: Callable[[ProcCorrNet], None] | None = None,
    weight: torch.Tensor | None = None,
) -> torch.Tensor:
    """One optimisation step; returns the batch's mean Euclidean distance (before the step,
    unweighted) as a 0-d tensor on the model's device: reading it waits for the step, so a
    training loop reads them at its evaluations (:func:`train_step` reads it at once).

    Args:
        src: (B, N, 3) points of the shapes' parts (part frames). Without ``context`` they are the
            context and ``dst (B, Q, 3)``, Q <= N, holds the cage targets (template frame) of the
            first Q of them. With ``context (B, N, 3)`` they are Q queries decoded against it and
            ``dst`` is (B, Q, 3) as well.
        loss: "mse" (mean squared distance) or "l2" (mean Euclidean distance).
        autocast: "none" or "bfloat16" (matrix products in bfloat16, loss in float32).
        grad_hook: called with the model between the backward pass and the update (data-parallel
            training averages the gradients across workers there).
        weight: (B, Q) non-negative per-target loss weights (the teacher's confidence); the loss
            is then their weighted mean.
    """
    if loss not in LOSSES:
        raise ValueError(f"loss must be one of {LOSSES}, got {loss!r}")
    ok = src.ndim == 3 and src.shape[-1] == 3 and dst.ndim == 3 and dst.shape[0] == src.shape[0] and dst.shape[-1] == 3
    if not ok or (dst.shape[1] > src.shape[1] if context is None else dst.shape != src.shape):
        raise ValueError(f"expected src (B, N, 3) and dst (B, Q, 3) with Q {'<=' if context is None else '=='} N, got {tuple(src.shape)} and {tuple(dst.shape)}")
    model.train()
    with _autocast(src.device, autocast):
        pred = model(src, dst.shape[1]) if context is None else model.decode(src, model.encode(context))
    dist2 = (pred.to(dst.dtype) - dst).square().sum(-1)
    dist = dist2.clamp_min(1e-20).sqrt()  # clamp: finite gradient of the "l2" loss at 0
    per = dist2 if loss == "mse" else dist
    if weight is None:
        value = per.mean()
    else:
        if weight.shape != per.shape:
            raise ValueError(f"weight must be {tuple(per.shape)}, got {tuple(weight.shape)}")
        w = weight.to(per.dtype)
        value = (w * per).sum() / w.sum().clamp_min(1e-12)
    optimiser.zero_grad(set_to_none=True)
    value.backward()
    if grad_hook is not None:
        grad_hook(model)
    optimiser.step()
    return dist.detach().mean()


def train_step(*args: Any, **kwargs: Any) -> float:
    """:func:`step_error`'s step (the same arguments), its error read as a float."""
    return float(step_error(*args, **kwargs))


def _error_summary(per_shape: list[np.ndarray]) -> dict[str, float]:
    if not per_shape:
        return {}
    allv = np.concatenate(per_shape)
    means = np.array([e.mean() for e in per_shape])
    return {
        "mean": float(means.mean()),
        "max": float(means.max()),
        "p95": float(np.percentile(allv, 95)),
        "max_point": float(allv.max()),
        "max_shape_mean": float(means.max()),
        "shapes": len(per_shape),
        "points": int(len(allv)),
    }


def eval_step(model: ProcCorrNet, pairs: Sequence[Pair], seed: int = 0, chunk: int = 8192, autocast: str = "none") -> dict[str, float]:
    """Pseudo-ground-truth error of the network on ``pairs`` (docs/results.md).

    For every pair the global feature is pooled over ``model.context_points`` samples of ``src``
    (seeded by ``seed``) and every ``src`` point is predicted; the error is the Euclidean distance to
    ``dst`` in the template part's normalised frame.

    Returns:
        ``mean``: mean over shapes of the per-shape mean (pairs of equal n: the mean over points);
        ``p95`` and ``max_point``: over all points of all shapes; ``max_shape_mean``: the largest
        per-shape mean; ``max``: the paper's "max", read as ``max_shape_mean`` (its sofa row has
        max / mean = 2.3; measured on the sofa data, max_shape_mean / mean is 1.7-1.9 and
        max_point / mean 3-7);
        ``shapes``, ``points``. Empty dict for no pairs.
    """
    pairs = check_pairs(pairs, "eval pairs", allow_empty=True)
    rng = np.random.default_rng(seed)
    errors = []
    for src, dst in pairs:
        ctx = src[sample_indices(len(src), model.context_points, rng)]
        pred = predict(model, ctx, src, chunk=chunk, autocast=autocast)
        errors.append(np.linalg.norm(pred - dst, axis=1))
    return _error_summary(errors)


@dataclass
class TrainResult:
    """Outcome of :func:`train`.

    Attributes:
        model: the network in its best validation state (the final state without validation
            pairs), in eval mode.
        history: one dict per evaluation: ``iteration``, ``lr``, ``train_error`` (mean Euclidean
            distance over the steps since the last evaluation), ``seconds`` and ``val_*`` figures.
        best_val: :func:`eval_step` of the kept state plus its ``iteration`` ({} without validation).
        iterations: steps run; seconds: wall time; stopped_early: patience ran out.
    """

    model: ProcCorrNet
    history: list[dict[str, Any]]
    best_val: dict[str, Any]
    iterations: int
    seconds: float
    stopped_early: bool
    config: CorrNetConfig = field(default_factory=CorrNetConfig)


def train(
    train_pairs: Sequence[Pair],
    val_pairs: Sequence[Pair] | None,
    config: CorrNetConfig | None = None,
    on_eval: Callable[[dict[str, Any]], None] | None = None,
    rank: int = 0,
    world: int = 1,
    grad_hook: Callable[[ProcCorrNet], None] | None = None,
    weights: Sequence[np.ndarray] | None = None,
    features: np.ndarray | None = None,
) -> TrainResult:
    """Train one ProcCorrNet on cage pairs of one template group.

    Args:
        train_pairs: sequence of ``(src (n, 3), dst (n, 3))`` arrays (see :func:`check_pairs`).
        val_pairs: held-out pairs for early stopping and model selection (may be empty / None:
            then the final state is kept and nothing stops early).
        config: settings (defaults: :class:`CorrNetConfig`).
        on_eval: called with each history entry (progress reporting).
        rank, world, grad_hook: data-parallel training. Each of ``world`` workers draws its own
            ``ceil(shapes_per_batch / world)`` shapes per step (seeded by the seed and its rank) and
            ``grad_hook`` averages the gradients across workers, so all workers keep identical
            weights and take identical early-stopping decisions (validation is the same everywhere).
        weights: per train pair ``(n,)`` loss weights of its points; default: the teacher's
            confidence by ``config.confidence`` (:mod:`proctex.correspond.confidence`; none with
            "none"). Every rank computes the same ones from the same pairs.
        features: ``(len(train_pairs), p)`` what the confidence finds each pair's neighbours by
            (the shapes' procedural parameters); None: by shape.

    Same seed, same data, same device -> identical weights (CPU); ``world=1`` is the single-process run.
    """
    if not (isinstance(world, int) and world >= 1 and isinstance(rank, int) and 0 <= rank < world):
        raise ValueError(f"need 0 <= rank < world, got rank {rank!r}, world {world!r}")
    config = (config or CorrNetConfig()).validate()
    t0 = time.perf_counter()
    data = GroupData.prepare(train_pairs, val_pairs, config, weights, features)
    model = build_model(config)
    device, dtype = _model_spec(model)
    data.set_extent(model)
    watch = EarlyStop(config, data.val, t0, on_eval)
    if settle_plain(model, data, config) is not None:  # the plain map is as good as any network could show
        watch.start(model)
        return watch.result(model, 0)
    autocast = resolve_autocast(config.autocast, device) if dtype == torch.float32 else "none"
    # fused on CUDA: one launch a step for every tensor (a small network's step is launch-bound there)
    optimiser = torch.optim.Adam(model.parameters(), lr=config.lr, weight_decay=config.weight_decay, fused=True if device.type == "cuda" else None)
    rng = np.random.default_rng(config.seed if world == 1 else [config.seed, rank])
    per_rank = -(-config.shapes_per_batch // world)
    if config.zero_init and config.residual:
        watch.start(model)  # the frame's own map (the box map) is a candidate like any other state
    step = 0
    pending: list[torch.Tensor] = []  # each step's training error, read at evaluations: no step waits for the device
    while step < config.iterations:
        lr = learning_rate(config, step)
        for g in optimiser.param_groups:
            g["lr"] = lr
        ctx, qry, tgt, wq = (torch.as_tensor(a, device=device, dtype=dtype) for a in sample_batch(data.train, config, rng, per_rank, data.weights))
        wq = wq if data.weights is not None else None
        if config.query_mode == "context":  # queries = the first Q context points: one encoder pass
            pending.append(step_error(model, optimiser, ctx, tgt, None, config.loss, autocast, grad_hook, wq))
        else:
            pending.append(step_error(model, optimiser, qry, tgt, ctx, config.loss, autocast, grad_hook, wq))
        step += 1
        if step % config.eval_every == 0 or step >= config.iterations:
            watch.window.extend(float(e) for e in torch.stack(pending).float().cpu().numpy())  # one read since the last evaluation
            pending.clear()
            if watch.evaluate(model, step, lr):
                break
    return watch.result(model, step)


@dataclass
class GroupData:
    """One group's checked training data (:meth:`prepare`): train and validation pairs and the
    train points' loss weights (None: all alike)."""

    train: list[Pair]
    val: list[Pair]
    weights: list[np.ndarray] | None

    @classmethod
    def prepare(
        cls, train_pairs: Sequence[Pair], val_pairs: Sequence[Pair] | None, config: CorrNetConfig, weights: Sequence[np.ndarray] | None = None, features: np.ndarray | None = None
    ) -> "GroupData":
        """Check the pairs (:func:`check_pairs`) and the weights (default: the teacher's confidence
        by ``config.confidence``); ``ValueError`` names what is wrong."""
        train_pairs = check_pairs(train_pairs, "train pairs")
        val_pairs = check_pairs(val_pairs or [], "val pairs", allow_empty=True)
        if weights is None and config.confidence == "neighbours":
            from .confidence import confidence_weights, neighbour_disagreement

            weights = confidence_weights(neighbour_disagreement(train_pairs, k=config.confidence_neighbours, seed=config.seed, features=features), scale=config.confidence_scale)
        if weights is not None:
            weights = [np.asarray(w, dtype=np.float32) for w in weights]
            if len(weights) != len(train_pairs) or any(w.shape != (len(s),) for w, (s, _) in zip(weights, train_pairs)):
                raise ValueError("weights must hold one (n,) array per train pair, n its number of points")
            if any(not np.isfinite(w).all() or (w < 0).any() or w.sum() <= 0 for w in weights):
                raise ValueError("weights must be finite, non-negative and not all zero per pair")
        return cls(train_pairs, val_pairs, weights)

    def set_extent(self, model: ProcCorrNet) -> None:
        """A box-frame network's template half extents, from every train target point."""
        if model.frame == "box":
            extent = np.max([np.abs(dst).max(axis=0) for _, dst in self.train], axis=0)
            model.template_extent.copy_(torch.as_tensor(np.maximum(extent, MIN_EXTENT), dtype=model.template_extent.dtype))


class EarlyStop:
    """One network's evaluations, best state and early stopping (shared by :func:`train` and
    :func:`proctex.correspond.grouped.train_together`): :meth:`evaluate` every ``eval_every``
    steps keeps the best validation state and says when patience has run out. The held-out error
    is measured in float32 whatever the training's autocast (as the serving choice measures it)."""

    def __init__(self, config: CorrNetConfig, val_pairs: list[Pair], t0: float, on_eval: Callable[[dict[str, Any]], None] | None = None) -> None:
        self.config, self.val, self.t0, self.on_eval = config, val_pairs, t0, on_eval
        self.history: list[dict[str, Any]] = []
        self.window: list[float] = []
        self.best_state: dict[str, Any] | None = None
        self.best_val: dict[str, Any] = {}
        self.best_mean, self.bad, self.stopped = math.inf, 0, False

    def _record(self, entry: dict[str, Any]) -> None:
        self.history.append(entry)
        if self.on_eval is not None:
            self.on_eval(entry)

    def start(self, model: ProcCorrNet) -> None:
        """Evaluate the untrained state (a zero-initialised residual network: the frame's map)."""
        if not self.val:
            return
        val = eval_step(model, self.val, seed=self.config.seed)
        self.best_mean, self.best_state, self.best_val = val["mean"], copy.deepcopy(model.state_dict()), {**val, "iteration": 0}
        self._record({"iteration": 0, "lr": learning_rate(self.config, 0), "train_error": float("nan"), "seconds": time.perf_counter() - self.t0, **{f"val_{k}": v for k, v in val.items()}})

    def evaluate(self, model: ProcCorrNet, step: int, lr: float) -> bool:
        """Record an evaluation after ``step`` steps; True when training should stop early."""
        cfg = self.config
        entry: dict[str, Any] = {"iteration": step, "lr": lr, "train_error": float(np.mean(self.window)), "seconds": time.perf_counter() - self.t0}
        self.window = []
        if self.val:
            val = eval_step(model, self.val, seed=cfg.seed)
            entry.update({f"val_{k}": v for k, v in val.items()})
            if self.best_state is None or val["mean"] < self.best_mean * (1 - cfg.min_delta):
                self.best_mean, self.bad = val["mean"], 0
                self.best_state, self.best_val = copy.deepcopy(model.state_dict()), {**val, "iteration": step}
            else:
                self.bad += 1
        self._record(entry)
        self.stopped = bool(cfg.patience and self.bad >= cfg.patience and step >= cfg.min_iterations)
        return self.stopped

    def result(self, model: ProcCorrNet, step: int) -> "TrainResult":
        """The network in its best validation state (the last without validation), in eval mode."""
        if self.best_state is not None:
            model.load_state_dict(self.best_state)
        model.eval()
        return TrainResult(model, self.history, self.best_val, step, time.perf_counter() - self.t0, self.stopped, self.config)


# ------------------------------------------------------------------------------------ serving choice
#: What can serve a group at run time: its network, the box map (each axis of the part's normalised
#: frame scaled from the part's half extents to the template part's: the network's zero residual in
#: the box frame) or the identity (the normalised frames taken to coincide).
SERVING = ("network", "box", "identity")
#: The network serves a group only when its held-out error is below ``1 - SERVE_MARGIN`` times the
#: best map without it: the held-out shapes also chose the network's kept state (early stopping),
#: which favours it a little, and a tie should cost nothing at run time.
SERVE_MARGIN = 0.05
#: ... and only when it gains more than this (normalised frame): below it two maps are the same map
#: to float rounding (a network left at the box map measured 1.47e-8 against the box map's 1.63e-8).
SERVE_FLOOR = 1e-6


def part_extent(points: np.ndarray) -> np.ndarray:
    """(3,) half extents of a part's points in its normalised frame, at least ``MIN_EXTENT`` (as the
    box-frame network reads them from its context)."""
    return np.maximum(np.abs(np.asarray(points, dtype=np.float64)).max(axis=0), MIN_EXTENT)


def box_map(points: np.ndarray, extent: np.ndarray, template_extent: np.ndarray) -> np.ndarray:
    """(n, 3) the box map of ``points (n, 3)`` (normalised frame, half extents ``extent (3,)``)
    onto a template part of half extents ``template_extent (3,)``: each axis scaled."""
    return np.asarray(points, dtype=np.float64) / np.asarray(extent, dtype=np.float64) * np.asarray(template_extent, dtype=np.float64)


def template_extent(pairs: Sequence[Pair]) -> np.ndarray:
    """(3,) the template part's half extents from the target points of ``pairs`` (at least
    ``MIN_EXTENT``), as :func:`train` sets a box-frame network's."""
    pairs = check_pairs(pairs, "pairs")
    return np.maximum(np.max([np.abs(dst).max(axis=0) for _, dst in pairs], axis=0), MIN_EXTENT)


def plain_errors(pairs: Sequence[Pair], extent: np.ndarray) -> dict[str, float]:
    """``{"box", "identity"}``: the mean over ``pairs`` of the per-shape mean distance from each
    plain map's image of the source points to the cage points (the box map onto half extents
    ``extent (3,)``)."""
    extent = np.asarray(extent, dtype=np.float64)
    return {
        "box": float(np.mean([np.linalg.norm(box_map(s, part_extent(s), extent) - d, axis=1).mean() for s, d in pairs])),
        "identity": float(np.mean([np.linalg.norm(s - d, axis=1).mean() for s, d in pairs])),
    }


def plain_fit(train_pairs: Sequence[Pair], val_pairs: Sequence[Pair] | None, config: CorrNetConfig) -> dict[str, float] | None:
    """Whether a group needs no training (``config.plain_below``): the plain maps' held-out errors
    (:func:`plain_errors`, onto the template extent of the train targets) when the better of them
    lies within ``plain_below`` of the held-out cage points, else None (train it). Never without
    held-out pairs or a residual network (which could not stay at the plain map)."""
    if not (config.residual and config.plain_below > 0 and val_pairs):
        return None
    errors = plain_errors(val_pairs, template_extent(train_pairs))
    return errors if min(errors.values()) < config.plain_below else None


def settle_plain(model: ProcCorrNet, data: "GroupData", config: CorrNetConfig) -> dict[str, float] | None:
    """:func:`plain_fit` of a group's data; where it needs no training, ``model`` (a residual
    network) is set to the frame's own map (its last layer zeroed: the zero residual)."""
    errors = plain_fit(data.train, data.val, config)
    if errors is not None:
        zero_residual(model)
    return errors


@dataclass
class ServingChoice:
    """What serves one group at run time (:func:`choose_serving`).

    Attributes:
        serve: one of :data:`SERVING`.
        errors: held-out mean error (mean over shapes of the per-shape mean distance to the cage
            points, the template part's normalised frame) of each candidate.
        template_extent: (3,) half extents the box map scales to.
        shapes: held-out shapes the choice was made on; margin: :data:`SERVE_MARGIN` as used.
    """

    serve: str
    errors: dict[str, float]
    template_extent: np.ndarray
    shapes: int
    margin: float

    def to_dict(self) -> dict[str, Any]:
        return {"serve": self.serve, "errors": dict(self.errors), "template_extent": [float(x) for x in self.template_extent], "shapes": self.shapes, "margin": self.margin}


def choose_serving(model: ProcCorrNet, val_pairs: Sequence[Pair], extent: np.ndarray, margin: float = SERVE_MARGIN, seed: int = 0) -> ServingChoice:
    """Network, box map or identity for one group, from held-out pairs (never ground truth).

    Each candidate maps every source point of ``val_pairs`` (the network as :func:`eval_step` does);
    its error is the mean over shapes of the per-shape mean distance to the cage points. The network
    serves when its error is below ``(1 - margin)`` x the better of the two maps without it, by more
    than :data:`SERVE_FLOOR`; else that map (the box map on a tie). ``extent (3,)``: the template
    part's half extents (:func:`template_extent`).
    """
    if not 0.0 <= margin < 1.0:
        raise ValueError(f"margin must be in [0, 1), got {margin!r}")
    val_pairs = check_pairs(val_pairs, "val pairs")
    extent = np.asarray(extent, dtype=np.float64)
    if extent.shape != (3,) or not np.all(np.isfinite(extent)) or np.any(extent <= 0):
        raise ValueError(f"extent must be three positive finite half extents, got {extent!r}")
    errors = {"network": float(eval_step(model, val_pairs, seed=seed)["mean"]), **plain_errors(val_pairs, extent)}
    plain = min(("box", "identity"), key=lambda k: (errors[k], k != "box"))
    gain = errors[plain] - errors["network"]
    serve = "network" if errors["network"] < (1.0 - margin) * errors[plain] and gain > SERVE_FLOOR else plain
    return ServingChoice(serve, errors, extent, len(val_pairs), float(margin))
