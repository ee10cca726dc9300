"""Several groups' ProcCorrNets trained together in one loop (:func:`train_together`).

Every group keeps its own network, batches, Adam state, evaluations, early stopping and best
state, exactly as :func:`proctex.correspond.training.train` gives it; what is shared is the step:
the groups' parameters are stacked (``torch.func.stack_module_state``) and one vectorised forward
and backward pass (``torch.func.vmap`` over ``functional_call``) runs all groups' batches as
batched matrix products. The loss is the sum of the groups' losses, so each group's gradient is
its own; Adam is elementwise, so the stacked optimiser takes each group's own steps. A group that
stops early leaves the stack (its parameters and Adam moments are sliced out), so it costs nothing
after.

What it buys is fewer, larger tensor programs: one Python step instead of one per group, and
matrix products large enough for every thread (or a GPU) instead of one small network per
process; on Ray, all of a team's groups in one Ray Train worker loop.
"""

from __future__ import annotations

import copy
import time
from typing import Any, Callable, Sequence

import numpy as np
import torch

from .corrnet import LOSSES, CorrNetConfig, Pair, ProcCorrNet, _autocast, _model_spec, build_model, resolve_autocast
from .training import EarlyStop, GroupData, TrainResult, learning_rate, sample_batch, settle_plain
from proctex.torch_kernels import resolve_vml

resolve_vml()  # MKL's kernels chosen on one thread (see proctex.torch_kernels)


class StackedParameters:
    """The stacked parameters of the groups still training, shaped like a module for a
    ``grad_hook`` (:meth:`parameters` yields each stacked ``(G, ...)`` tensor)."""

    def __init__(self, params: dict[str, torch.Tensor]) -> None:
        self.params = params

    def parameters(self):
        return iter(self.params.values())


def group_losses(
    base: ProcCorrNet, params: dict[str, torch.Tensor], buffers: dict[str, torch.Tensor], ctx: torch.Tensor, tgt: torch.Tensor, weight: torch.Tensor | None, loss: str = "mse", autocast: str = "none"
) -> tuple[torch.Tensor, torch.Tensor]:
    """Each group's training loss and mean distance, as :func:`proctex.correspond.training.train_step`
    computes them for one network.

    Args:
        base: a network of the groups' architecture (its own weights are not used).
        params, buffers: stacked ``(G, ...)`` (:func:`torch.func.stack_module_state`).
        ctx: (G, B, N, 3) contexts; tgt: (G, B, Q, 3) targets of the first Q context points;
        weight: (G, B, Q) per-target loss weights or None.

    Returns ``(loss (G,), mean distance (G,))``.
    """
    if loss not in LOSSES:
        raise ValueError(f"loss must be one of {LOSSES}, got {loss!r}")
    q = tgt.shape[2]

    def one(p, b, c):
        return torch.func.functional_call(base, (p, b), (c, q))

    with _autocast(ctx.device, autocast):
        pred = torch.vmap(one)(params, buffers, ctx)
    dist2 = (pred.to(tgt.dtype) - tgt).square().sum(-1)  # (G, B, Q)
    dist = dist2.clamp_min(1e-20).sqrt()
    per = dist2 if loss == "mse" else dist
    if weight is None:
        value = per.mean(dim=(1, 2))
    else:
        w = weight.to(per.dtype)
        value = (w * per).sum(dim=(1, 2)) / w.sum(dim=(1, 2)).clamp_min(1e-12)
    return value, dist.detach().mean(dim=(1, 2))


def _adam(params: dict[str, torch.Tensor], config: CorrNetConfig) -> torch.optim.Adam:
    """Adam over the stacked parameters; on CUDA its fused kernel (one launch a step for every
    tensor: a step of a small network is launch-bound there), elsewhere torch's default."""
    cuda = next(iter(params.values())).is_cuda
    return torch.optim.Adam(params.values(), lr=config.lr, weight_decay=config.weight_decay, fused=True if cuda else None)


def _restack(params: dict[str, torch.Tensor], optimiser: torch.optim.Adam, keep: list[int], config: CorrNetConfig) -> tuple[dict[str, torch.Tensor], torch.optim.Adam]:
    """The stack and its Adam state with only the rows ``keep`` (groups still training)."""
    index = torch.as_tensor(keep, dtype=torch.long)
    new = {k: v.detach()[index].clone().requires_grad_(True) for k, v in params.items()}
    opt = _adam(new, config)
    for (k, old), p in zip(params.items(), new.values()):
        state = optimiser.state.get(old)
        if state:
            opt.state[p] = {name: (v[index].clone() if torch.is_tensor(v) and v.ndim > 0 else copy.deepcopy(v)) for name, v in state.items()}
    return new, opt


def _unstack(params: dict[str, torch.Tensor], row: int, model: ProcCorrNet) -> None:
    """Copy stack row ``row`` into ``model``'s parameters."""
    with torch.no_grad():
        named = dict(model.named_parameters())
        for k, v in params.items():
            named[k].copy_(v[row])


def train_together(
    groups: Sequence[tuple[Sequence[Pair], Sequence[Pair] | None]],
    config: CorrNetConfig | None = None,
    weights: Sequence[Sequence[np.ndarray] | None] | None = None,
    features: Sequence[np.ndarray | None] | None = None,
    on_eval: Callable[[int, dict[str, Any]], None] | None = None,
    rank: int = 0,
    world: int = 1,
    grad_hook: Callable[[Any], None] | None = None,
) -> list[TrainResult]:
    """Train one network per group in one loop; the same networks as training each with
    :func:`proctex.correspond.training.train` (same seed, batches and schedule per group), to float
    rounding of the batched products.

    Args:
        groups: per group ``(train_pairs, val_pairs)`` (see :func:`proctex.correspond.training.train`).
        config: the settings every group trains with (``query_mode`` "context").
        weights, features: per group, as :func:`proctex.correspond.training.train`'s.
        on_eval: called with ``(group index, history entry)``.
        rank, world, grad_hook: data-parallel training as :func:`proctex.correspond.training.train`;
            the hook gets a :class:`StackedParameters` (every group's gradients in one tensor per layer).

    Returns one :class:`TrainResult` per group, in order.
    """
    if not (isinstance(world, int) and world >= 1 and isinstance(rank, int) and 0 <= rank < world):
        raise ValueError(f"need 0 <= rank < world, got rank {rank!r}, world {world!r}")
    config = (config or CorrNetConfig()).validate()
    if config.query_mode != "context":
        raise ValueError("training groups together needs query_mode 'context' (train them one by one otherwise)")
    groups = list(groups)
    if not groups:
        raise ValueError("no groups to train")
    weights = list(weights) if weights is not None else [None] * len(groups)
    features = list(features) if features is not None else [None] * len(groups)
    if len(weights) != len(groups) or len(features) != len(groups):
        raise ValueError("weights and features need one entry per group")
    t0 = time.perf_counter()
    data = [GroupData.prepare(tp, vp, config, w, f) for (tp, vp), w, f in zip(groups, weights, features)]
    models = [build_model(config) for _ in groups]
    device, dtype = _model_spec(models[0])
    autocast = resolve_autocast(config.autocast, device) if dtype == torch.float32 else "none"
    watches, active = [], []
    for g, (d, m) in enumerate(zip(data, models)):
        d.set_extent(m)
        watches.append(EarlyStop(config, d.val, t0, None if on_eval is None else (lambda e, g=g: on_eval(g, e))))
        if settle_plain(m, d, config) is not None:  # not trained: it never joins the stack
            watches[-1].start(m)
            continue
        active.append(g)
        if config.zero_init and config.residual:
            watches[-1].start(m)
    steps = [0] * len(groups)
    if not active:
        return [w.result(m, s) for w, m, s in zip(watches, models, steps)]
    rngs = [np.random.default_rng(config.seed if world == 1 else [config.seed, rank]) for _ in groups]
    per_rank = -(-config.shapes_per_batch // world)
    base = copy.deepcopy(models[0]).to("meta")
    params, buffers = torch.func.stack_module_state([models[g] for g in active])
    optimiser = _adam(params, config)
    pending: list[torch.Tensor] = []  # each step's (groups,) training errors, read at evaluations

    def read_pending() -> None:
        # one read of the steps' errors since the last evaluation: no step waits for the device
        if pending:
            errors = torch.stack(pending).float().cpu().numpy()
            for row, g in enumerate(active):
                watches[g].window.extend(float(e) for e in errors[:, row])
            pending.clear()

    step = 0
    while step < config.iterations and active:
        lr = learning_rate(config, step)
        for pg in optimiser.param_groups:
            pg["lr"] = lr
        batches = [sample_batch(data[g].train, config, rngs[g], per_rank, data[g].weights) for g in active]
        ctx, _, tgt, wq = (torch.as_tensor(np.stack(a), device=device, dtype=dtype) for a in zip(*batches))
        use_w = any(data[g].weights is not None for g in active)
        value, dist = group_losses(base, params, buffers, ctx, tgt, wq if use_w else None, config.loss, autocast)
        optimiser.zero_grad(set_to_none=True)
        value.sum().backward()
        if grad_hook is not None:
            grad_hook(StackedParameters(params))
        optimiser.step()
        pending.append(dist.detach())
        step += 1
        if step % config.eval_every and step < config.iterations:
            continue
        read_pending()
        stopped = []
        for row, g in enumerate(active):
            _unstack(params, row, models[g])
            steps[g] = step
            if watches[g].evaluate(models[g], step, lr):
                stopped.append(g)
        if stopped:
            keep = [row for row, g in enumerate(active) if g not in stopped]
            active = [g for g in active if g not in stopped]
            if active:
                params, optimiser = _restack(params, optimiser, keep, config)
                buffers = {k: v[torch.as_tensor(keep, dtype=torch.long)] for k, v in buffers.items()}
    for row, g in enumerate(active):
        _unstack(params, row, models[g])
        steps[g] = step
    return [w.result(m, s) for w, m, s in zip(watches, models, steps)]
