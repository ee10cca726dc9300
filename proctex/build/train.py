"""The ``train`` stage: one ProcCorrNet per part group on its cage pairs, and what serves each group."""

from __future__ import annotations

import time
from typing import Any, Callable

from proctex.build.groupdata import VAL_SHARE, group_training_data, plain_groups, trainable_groups
from proctex.build.plan import Plan
from proctex.correspond.corrnet import to_bytes, trains_together
from proctex.correspond.grouped import train_together
from proctex.correspond.training import choose_serving, template_extent, train
from proctex.store.config import BuildConfig
from proctex.store.layout import FamilyStore, StoreLayout
from proctex.store.networks import save_network
from proctex.store.state import FamilyState, stage_done


def serving_choice(model: Any, data: dict[str, Any]) -> dict[str, Any]:
    """What serves a group at run time (:func:`proctex.correspond.training.choose_serving`): its
    network, the box map or the identity, chosen on the group's held-out train pairs (``data``, from
    :func:`group_training_data`; never ground truth). ``held_out`` False: the group had too few
    shapes to hold one out and the choice was made on a training pair, which favours the network."""
    extent = model.template_extent.detach().cpu().numpy() if model.frame == "box" else template_extent(data["train"])
    return {**choose_serving(model, data["val"], extent).to_dict(), "held_out": bool(data["val_ids"])}


def serving_line(serving: dict[str, Any] | None) -> str:
    """One line for a log: what serves the group and the held-out errors it was chosen on."""
    if not serving:
        return "the network serves"
    errs = ", ".join(f"{k} {v:.4f}" for k, v in serving["errors"].items())
    what = {"box": "box map"}.get(serving["serve"], serving["serve"])
    return f"the {what} serves (held-out errors: {errs}{'' if serving.get('held_out', True) else '; no held-out shape'})"


def save_group_model(store: FamilyStore, group: int, result, cfg, data: dict[str, Any]) -> tuple[str, dict[str, Any]]:
    """Write a trained group network to ``models/group_<g>.pt`` (atomically) with its serving choice
    (:func:`serving_choice`); returns its checksum (:func:`proctex.store.layout.digest`) and that
    choice, which the train stage records."""
    serving = serving_choice(result.model, data)
    extra = {"group": group, "train_ids": data["train_ids"], "val_ids": data["val_ids"], "best_val": result.best_val, "serving": serving}
    return save_network(store, group, to_bytes(result.model, cfg, extra)), serving


def fit_groups(
    store: FamilyStore, config: BuildConfig, groups: list[int], rank: int = 0, world: int = 1, grad_hook: Callable[[Any], None] | None = None, data: dict[int, dict[str, Any]] | None = None
) -> list[dict[str, Any]]:
    """Train the networks of ``groups`` (together in one batched loop where
    :func:`proctex.correspond.corrnet.trains_together` says so, each keeping its own network, early
    stopping and best state; else one after another) and, on ``rank`` 0, store each; the one train
    body of every executor (in process; each Ray Train worker of a team of ``world``, with
    ``grad_hook`` averaging the gradients). Returns per group its train record, the same fields
    whoever trained it: ``best_val`` (:func:`proctex.correspond.training.eval_step` of the kept
    state), ``iterations``, ``seconds`` (a shared loop's for groups trained together),
    ``train_pairs``, ``val_pairs``, ``sha256`` and ``serving`` (None off rank 0), ``workers`` (the
    team's size: 1 in process) and ``together`` (the groups trained in the same loop). ``data``:
    ``{group: group_training_data(...)}`` a caller has read already."""

    def load(g: int) -> dict[str, Any]:  # ``data``: groups' training data already read by the caller
        return data[g] if data and g in data else group_training_data(store, config, g, VAL_SHARE)

    if not trains_together(config.train, len(groups)):
        out = []
        for g in groups:  # one after another, each stored as it finishes
            d = load(g)
            t = time.perf_counter()
            result = train(d["train"], d["val"], config.train, rank=rank, world=world, grad_hook=grad_hook, features=d["features"])
            out.append(_group_record(store, config, g, d, result, time.perf_counter() - t, rank, world, 1))
        return out
    loaded = [load(g) for g in groups]
    t = time.perf_counter()
    results = train_together([(d["train"], d["val"]) for d in loaded], config.train, features=[d["features"] for d in loaded], rank=rank, world=world, grad_hook=grad_hook)
    seconds = time.perf_counter() - t
    return [_group_record(store, config, g, d, r, seconds, rank, world, len(groups)) for g, d, r in zip(groups, loaded, results)]


def _group_record(store: FamilyStore, config: BuildConfig, group: int, data: dict[str, Any], result, seconds: float, rank: int, world: int, together: int) -> dict[str, Any]:
    sha, serving = save_group_model(store, group, result, config.train, data) if rank == 0 else (None, None)
    return {
        "best_val": result.best_val,
        "iterations": result.iterations,
        "seconds": round(seconds, 2),
        "train_pairs": len(data["train"]),
        "val_pairs": len(data["val"]),
        "sha256": sha,
        "serving": serving,
        "workers": world,
        "together": together,
    }


def run_train_batch(store: FamilyStore, config: BuildConfig, groups: list[int], context: Any = None) -> list[dict[str, Any]]:
    """Train and store the networks of ``groups`` in this process (:func:`fit_groups`)."""
    return fit_groups(store, config, groups)


def _stage_record(record: dict[str, Any]) -> dict[str, Any]:
    """A group's train record as the stage keeps it (without the pair counts of the log line)."""
    return {k: v for k, v in record.items() if k not in ("train_pairs", "val_pairs")}


def plan_train(store: FamilyStore, config: BuildConfig, log: Callable[[str], None] = print) -> Plan:
    """The train stage: one ProcCorrNet per trainable group without one yet, a batch per group. A
    resumed build keeps the record of the groups trained before. A worker's groups go to
    :func:`fit_groups` (in one batched loop where that pays: ``merge``), on Ray by a team of
    workers each (``team``); an executor may set ``info["mark"]`` (extra fields for the stage's
    record)."""
    before = FamilyState.load(store).stage("train").get("groups", {})
    groups = trainable_groups(store)
    todo = [g for g in groups if not store.exists(StoreLayout.model(g))]
    trained: dict[Any, Any] = {}
    for g in groups:
        if g not in todo:
            log(f"train: group {g} done already")
            if str(g) in before:
                trained[g] = before[str(g)]
    if not todo and stage_done(store, "train"):
        return Plan("train", [], run_train_batch, finish=lambda results: None, skip="done already")

    def collect(batch: list[int], out: list[dict[str, Any] | None]) -> None:
        for g, m in zip(batch, out):
            if m is not None and "train_pairs" in m:
                how = f"{m['iterations']} iterations" if m["iterations"] else f"not trained (a plain map within {config.train.plain_below:g})"
                log(f"train: group {g}: {m['train_pairs']} train / {m['val_pairs']} val pairs, val {m['best_val']}, {how}, {m['seconds']}s; {serving_line(m.get('serving'))}")

    # Groups whose plain map already fits (CorrNetConfig.plain_below) are settled here, before any
    # worker starts: no pool slot or Ray Train team waits on them (teams are dealt statically).
    settled = plain_groups(store, config, todo)
    if settled:
        records = fit_groups(store, config, list(settled), data=settled)
        collect(list(settled), records)
        trained.update((g, _stage_record(m)) for g, m in zip(settled, records))
        todo = [g for g in todo if g not in settled]

    def finish(results: list[list[dict[str, Any] | None]]) -> dict[str, Any] | None:
        for g, m in zip(todo, (m for out in results for m in out)):
            if m is not None:
                trained[g] = _stage_record(m)
        if todo or not stage_done(store, "train"):
            return {"groups": trained, **plan.info.get("mark", {})}
        return None

    # in process, groups side by side in worker processes of one thread (Plan.parallel: demo 74.0 -> 62.0 s,
    # sofa export 209.7 -> 194.8 s on 2 cores); each worker's share trained in one batched loop where
    # that pays (Plan.merge; CorrNetConfig.together: on a GPU)

    plan = Plan("train", [[g] for g in todo], run_train_batch, finish, collect, team=fit_groups, parallel=True, merge=trains_together(config.train, len(todo)))
    return plan
