"""The networks record: every stored group network, checked against the train stage's record."""

from __future__ import annotations

from typing import Any

import numpy as np

from proctex.store.layout import FamilyStore, StoreLayout, check_digest, digest
from proctex.store.state import FamilyState


def save_network(store: FamilyStore, group: int, blob: bytes) -> str:
    """Store group ``group``'s network (:func:`proctex.correspond.corrnet.to_bytes`) as
    ``models/group_<g>.pt``, atomically; returns the checksum the train stage records for it
    (:func:`load_models` checks it)."""
    store.write_bytes(StoreLayout.model(group), blob)
    return digest(blob)


def load_models(store: FamilyStore, device: str = "cpu", state: FamilyState | None = None) -> dict[int, Any]:
    """{group: ProcCorrNet} of every stored model. A network whose file holds another group's, or
    whose checksum differs from the train stage's record (in ``state``, read here when None), is a
    ``ValueError`` naming the file."""
    from proctex.correspond.corrnet import from_bytes

    recorded = (state if state is not None else FamilyState.load(store)).stage("train").get("groups", {})
    models = {}
    for name in store.listdir(StoreLayout.MODELS):
        g = StoreLayout.model_group(name)
        if g is None:
            continue
        where = store.path(StoreLayout.model(g))
        blob = store.read_bytes(StoreLayout.model(g))
        check_digest(blob, (recorded.get(str(g)) or {}).get("sha256"), where)
        models[g], _, extra = from_bytes(blob, device=device, where=where)
        if int(extra.get("group", g)) != g:
            raise ValueError(f"{where}: holds the network of group {extra.get('group')}, not of group {g}")
        models[g].serving = check_serving(extra.get("serving"), where)
    return models


def check_serving(raw: Any, where: str) -> dict[str, Any] | None:
    """A stored serving choice (:func:`serving_choice`) checked: ``{"serve", "template_extent"}``
    with a known ``serve`` and three positive finite extents, else ``ValueError`` naming ``where``;
    None (networks trained before the choice existed: the network serves)."""
    from proctex.correspond.training import SERVING

    if raw is None:
        return None
    ext = raw.get("template_extent") if isinstance(raw, dict) else None
    ok = isinstance(raw, dict) and raw.get("serve") in SERVING and isinstance(ext, list) and len(ext) == 3 and all(isinstance(x, (int, float)) and np.isfinite(x) and x > 0 for x in ext)
    if not ok:
        raise ValueError(f"{where}: damaged serving choice {str(raw)[:200]!r}")
    return raw
