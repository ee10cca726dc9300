"""The words of a part's name, and how a prompt's word matches them: "arms" names "Left Arm",
"shelves" names "Shelf". Shared by the part words (:mod:`.partwords`) and the names a ``.blend``
model's node tree gives (:mod:`proctex.sources.provenance`)."""

from __future__ import annotations

import re

MAX_WORDS = 8

#: Words that qualify a part rather than name it: not matched against a prompt's part words.
QUALIFIERS = frozenset(
    """
left right front rear upper lower inner outer middle mid centre center central main small big large long short
first second third one two three four five six seven eight nine ten single double extra new old default
""".split()
)
#: Words that name no part: never matched against a prompt.
NOT_PARTS = frozenset(
    """
a an and of the with for rest part parts piece pieces geometry geo mesh meshes object objects shape shapes model node
nodes group groups instance instances collection data output input thing things element elements item items
""".split()
)


def label_words(label: str) -> list[str]:
    """The words of a label: CamelCase split, separators (space, ``_``, ``-``, ``.``) dropped, a
    trailing ``.001`` numbering and every number dropped. ``"CabinetBoardRight.002"`` ->
    ``["Cabinet", "Board", "Right"]``."""
    text = re.sub(r"\.\d+$", "", str(label)[:256])
    text = re.sub(r"(?<=[a-z])(?=[A-Z])|(?<=[A-Z])(?=[A-Z][a-z])", " ", text)
    return [w for w in re.findall(r"[A-Za-z]+", text) if w][: MAX_WORDS * 2]


def matchable_words(name: str, whole: frozenset[str] = frozenset()) -> list[str]:
    """The lower-case words of a part name a prompt's word can match: qualifiers ("left", "front"),
    words that name no part and the model's own words left out. ``"Left Arm"`` -> ``["arm"]``."""
    return [w.lower() for w in label_words(name) if len(w) > 1 and w.lower() not in QUALIFIERS | NOT_PARTS and w.lower() not in whole]


def same_word(a: str, b: str) -> bool:
    """``a`` and ``b`` are one word, up to a plural ("arm" / "arms", "shelf" / "shelves", "box" /
    "boxes", "body" / "bodies")."""
    a, b = a.lower(), b.lower()
    if a == b:
        return True
    short, long_ = sorted((a, b), key=len)
    return (
        long_ in (short + "s", short + "es")
        or (short.endswith("y") and long_ == short[:-1] + "ies")
        or (short.endswith("f") and long_ == short[:-1] + "ves")
        or (short.endswith("fe") and long_ == short[:-2] + "ves")
    )
