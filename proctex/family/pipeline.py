"""The in-process family build: the stage table and the loop that runs it.

The stages themselves live below this module (:mod:`proctex.family` for sample, template, paint,
pairs and train; :mod:`proctex.evaluate` for evaluate), so neither imports the other's stages back:
the table is assembled here, at the top, and handed to the loop. ``workflows/build.py`` runs the same
stages on Ray.
"""

from __future__ import annotations

import time
from typing import Any, Callable, Mapping

from .config import BuildConfig
from .evaluate import stage_evaluate
from .stages import STAGES, _state, stage_paint, stage_pairs, stage_sample, stage_template, stage_train, write_config
from .store import FamilyStore

#: Stage name -> ``runner(store, config, log=...)``, in :data:`proctex.family.stages.STAGES` order.
STAGE_RUNNERS: Mapping[str, Callable[..., None]] = {
    "sample": stage_sample,
    "template": stage_template,
    "paint": stage_paint,
    "pairs": stage_pairs,
    "train": stage_train,
    "evaluate": stage_evaluate,
}


def build(store: FamilyStore, config: BuildConfig, stages: tuple[str, ...] | list[str] = STAGES, log: Callable[[str], None] = print,
          runners: Mapping[str, Callable[..., None]] = STAGE_RUNNERS) -> dict[str, Any]:
    """Run the build ``stages`` in :data:`proctex.family.stages.STAGES` order with ``runners`` (stage ->
    ``runner(store, config, log=...)``; each skips what is complete). The one stage loop: the Ray
    build hands it a table whose fanned-out stages run on Ray (``workflows/build.py``). Returns the
    family state with ``wall_seconds`` per stage run. ``ValueError`` for a stage name the table does
    not know."""
    unknown = set(stages) - set(runners)
    if unknown:
        raise ValueError(f"unknown stages: {', '.join(sorted(unknown))}; known: {', '.join(runners)}")
    write_config(store, config)
    walls: dict[str, float] = {}
    for stage in STAGES:
        if stage in stages:
            t = time.perf_counter()
            runners[stage](store, config, log=log)
            walls[stage] = round(time.perf_counter() - t, 2)
    return {**_state(store), "wall_seconds": walls}
