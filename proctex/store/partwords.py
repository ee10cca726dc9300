"""The user's last word on which group is which part (``template/part_words.json``): ``{"groups":
{"3": "legs", ...}, "saved": time}``. Stored by ``proctex parts FAMILY --assign`` and the studio;
every look painted afterwards follows it (:func:`proctex.looks.add_look`), as do transfers of
those looks. Group indices are the template's (:class:`proctex.geometry.parts.Grouping`)."""

from __future__ import annotations

import time
from typing import Any

from proctex.store.layout import FamilyStore, StoreLayout
from proctex.store.locks import StoreBusy, store_lock
from proctex.texture.painters.partwords import check_assignment


def stored_part_words(store: FamilyStore) -> dict[str, str]:
    """The family's stored words per group (``{"3": "legs"}``; {} when none were saved). A damaged
    record is ``ValueError`` naming the file."""
    if not store.exists(StoreLayout.PART_WORDS):
        return {}
    data = store.read_json(StoreLayout.PART_WORDS)
    if not isinstance(data, dict):
        raise ValueError(f"{store.path(StoreLayout.PART_WORDS)}: not a part-words record")
    try:
        return {str(k): v for k, v in check_assignment(data.get("groups", {})).items()}
    except ValueError as exc:
        raise ValueError(f"{store.path(StoreLayout.PART_WORDS)}: {exc}") from None


def save_part_words(store: FamilyStore, words: Any, groups: int, replace: bool = False, timeout: float = 60.0) -> dict[str, str]:
    """Store the user's words per group (``{group index: word}``, :func:`check_assignment`; a
    family of ``groups`` groups) over those stored (``replace``: instead of them); an empty word
    removes a group's entry. Returns what is stored now. ``ValueError`` for a bad entry (nothing is
    written), :class:`proctex.store.locks.StoreBusy` while an edit holds the family past ``timeout``."""
    if not isinstance(words, dict):
        raise ValueError(f"part words must be an object {{group index: word}}, got {type(words).__name__}")
    cleared = {str(k) for k, v in words.items() if isinstance(v, str) and not v.strip()}
    given = {str(k): v for k, v in check_assignment({k: v for k, v in words.items() if str(k) not in cleared}, groups).items()}
    check_assignment({k: "rest" for k in cleared}, groups)  # the keys of cleared entries are group indices too
    with store_lock(store, StoreLayout.EDIT_LOCK, "saving part words", timeout=timeout, busy=StoreBusy):
        now = {} if replace else stored_part_words(store)
        now = {k: v for k, v in {**now, **given}.items() if k not in cleared}
        now = dict(sorted(now.items(), key=lambda kv: int(kv[0])))
        if now:
            store.write_json(StoreLayout.PART_WORDS, {"groups": now, "saved": time.strftime("%Y-%m-%dT%H:%M:%S")})
        elif store.exists(StoreLayout.PART_WORDS):
            store.delete(StoreLayout.PART_WORDS)
    return now
