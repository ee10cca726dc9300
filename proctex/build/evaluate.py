"""The ``evaluate`` stage: transfer to the test shapes and measure (:mod:`proctex.measure.evaluate`)."""

from __future__ import annotations

from typing import Any, Callable, Sequence

from proctex.build.plan import default_workers
from proctex.measure.evaluate import evaluate
from proctex.store.layout import FamilyStore, StoreLayout
from proctex.store.samples import samples
from proctex.store.state import stage_done


def evaluate_step(store: FamilyStore, config, log: Callable[[str], None] = print, methods: Sequence[str] = ("corrnet", "identity")) -> dict[str, Any] | None:
    """The ``evaluate`` build stage: :func:`evaluate` on the test shapes into ``metrics.json``;
    returns the stage's record (None: done already, or too few test shapes to measure)."""
    if stage_done(store, "evaluate"):
        log("evaluate: done already")
        return None
    tests = sum(r["split"] == "test" for r in samples(store))
    if tests < 2:
        log("evaluate: fewer than two test shapes, skipped")
        return None
    # shapes side by side in worker processes of one thread (a pool takes a few seconds to start:
    # from 4 shapes on); the same metrics as one after the other
    workers = default_workers() if tests >= 4 else 1
    metrics = evaluate(store, methods=methods, log=log, quiet=True, workers=workers)
    store.write_json(StoreLayout.METRICS, metrics)
    net = metrics["methods"]["corrnet"]
    return {
        "shapes": metrics["shapes"],
        "tracker": metrics["tracker"],
        "tracked_point_variance": net["tracked_point_variance"],
        "tracked_point_variance_realtime": net["tracked_point_variance_realtime"],
        "coverage": net["coverage"],
        "gt_error": net["gt_error"],
        "pgt_error": net["pgt_error"],
        "mapped_share": net["mapped_share"],
        "seconds_per_shape": net["seconds_per_shape"],
    }
