"""What the pairs and train stages both read of a group: its solved train pairs, the held-out share
for early stopping, and whether its plain map already fits (then it needs no network). A lower
module of the build, so neither stage imports the other."""

from __future__ import annotations

import json
from typing import Any

from proctex.correspond.confidence import param_features
from proctex.correspond.training import plain_fit
from proctex.store.config import BuildConfig
from proctex.store.layout import FamilyStore, StoreLayout
from proctex.store.samples import held_out_ids, read_pair, samples

VAL_SHARE = 0.15  # of a group's train shapes, held out for early stopping


def trainable_groups(store: FamilyStore) -> list[int]:
    """Groups with at least one solved train pair."""
    rows = store.read_table(StoreLayout.PAIRS).to_pylist() if store.exists(StoreLayout.PAIRS) else []
    return sorted({r["group"] for r in rows if r["status"] == "done" and r["split"] == "train"})


def group_training_data(store: FamilyStore, config: BuildConfig, group: int, val_share: float = 0.15) -> dict[str, Any]:
    """Train and validation pairs of one group: a seeded ``val_share`` of its train shapes is held
    out for early stopping. Returns ``{"train": [(src, dst)], "val": [...], "train_ids", "val_ids",
    "features"}``; ``features``: the train shapes' procedural parameters as the teacher's
    confidence finds neighbours by (:func:`proctex.correspond.confidence.param_features`; None
    where the shapes carry none or the confidence is off)."""
    rows = [r for r in store.read_table(StoreLayout.PAIRS).to_pylist() if r["status"] == "done" and r["split"] == "train" and r["group"] == group]
    ids = sorted(r["id"] for r in rows)
    if not ids:
        raise ValueError(f"group {group} has no solved train pairs")
    rows_all = samples(store)
    # held out: the family's draw over all its train shapes (the pairs stage solves these first)
    val_ids = held_out_ids([r["id"] for r in rows_all if r["split"] == "train"], ids, config.seed, group, val_share)
    held = set(val_ids)
    train_ids = [i for i in ids if i not in held]
    train_pairs = [read_pair(store, i, group) for i in train_ids]
    val_pairs = [read_pair(store, i, group) for i in val_ids] or train_pairs[:1]
    features = None
    if config.train.confidence != "none":  # only the teacher's confidence reads the parameters
        params = {r["id"]: r.get("params") for r in rows_all}
        features = param_features([json.loads(params.get(i) or "{}") for i in train_ids])
    return {"train": train_pairs, "val": val_pairs, "train_ids": train_ids, "val_ids": val_ids, "features": features}


def plain_groups(store: FamilyStore, config: BuildConfig, groups: list[int]) -> dict[int, dict[str, Any]]:
    """The groups of ``groups`` that need no training, with their training data (and under
    ``"plain"`` the plain maps' held-out errors): their plain map lies within ``train.plain_below``
    of their held-out pairs (:func:`proctex.correspond.training.plain_fit`; never a group without
    a held-out shape). A group whose data cannot be read is left to the training, which reports why."""
    if config.train.plain_below <= 0 or not config.train.residual:
        return {}
    out = {}
    for g in groups:
        try:
            d = group_training_data(store, config, g, VAL_SHARE)
        except ValueError:
            continue
        errors = plain_fit(d["train"], d["val"], config.train) if d["val_ids"] else None
        if errors is not None:
            out[g] = {**d, "plain": errors}
    return out
