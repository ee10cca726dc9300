"""Part words grounded in geometry: "a bed with a white linen mattress, a walnut headboard and black
metal legs" on a mesh whose parts carry no names.

Real exports (Blender, OBJ folders) name no parts, so a prompt's part nouns match no label. Each part
word of the vocabulary (:mod:`.partvocab`: words by kinds of object, with forms, plurals and
compounds) is a small scoring function of a part group's measured evidence in the shape's up frame
(shape of a member from its principal axes, height band, what it rests on and what rests on it,
repetition, place against the main mass, size). :func:`plan_parts` resolves the words of a prompt
to groups *jointly*: every clause gets its best group and a group its best clause (one assignment
problem over the scores, scipy's ``linear_sum_assignment``), then each group left joins the clause
that scores it best when that score is near the clause's own; ties and weak matches are reported.
The prompt's object noun ("a lamp") chooses the kind whose scorers are used (a mug's "handle" is not
a cabinet's); without one, the kind whose words the prompt uses most, else the best of every kind.

- a group a word took gets that word's clause ("red velvet" for the seat);
- a clause whose part word is unknown ("a gold antenna" on a chair) joins as a weak match: it takes the
  largest group no known word took, reported as a guess; with no group left it paints nothing and
  the notes say so. A clause's words never join another clause's material;
- a group no word took that passes the test of a word of the same kind as a word the prompt placed
  (:data:`KINDRED`: a chair's disc base or stretchers when the prompt names its legs) gets that
  word's clause;
- any other group no word took gets the rest of the prompt when the rest names a material ("an oak
  chair with a red velvet seat": oak), else the clause of the taken group most alike in shape (a
  back panel is a slab like the seat, arms are bars like the legs).

Labels, where a shape has them, come first: a word that names a group's label is routed by the
label (as :mod:`.regions` always did), and so is a word naming one word of a label of several words
(a ``.blend`` node tree's "Left Arm" for "arms", :func:`label_hits`); a group named by its label is
not taken by a word's geometric test.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from . import partvocab as V
from .names import matchable_words, same_word
from .prompt import parse_prompt
from .regions import RegionPlan, _label_of, split_regions

__all__ = [
    "PART_WORDS",
    "KINDRED",
    "GroupGeometry",
    "PartPlan",
    "describe_groups",
    "part_word",
    "resolve_words",
    "plan_parts",
    "new_part_texts",
    "label_hits",
    "groups_of_word",
    "check_assignment",
    "REST",
    "parts_report",
]

GroupGeometry = V.Evidence
#: canonical word -> its forms (the vocabulary, :data:`.partvocab.WORDS`)
PART_WORDS: dict[str, tuple[str, ...]] = {w: word.forms for w, word in V.WORDS.items()}
#: a clause's best group is taken only with at least this score
MIN_SCORE = 0.2
#: another group joins a clause that scores it at least this, and at least EXTEND_SHARE of the
#: clause's best group's score
EXTEND_SCORE, EXTEND_SHARE = 0.45, 0.6
#: two clauses within this of each other on a group are a tie (reported)
TIE = 0.05
#: shapes with more groups than this are resolved on the largest of them only (the others take the
#: rest of the prompt): a bound on the evidence's pairwise contacts
MAX_GROUPS = 200
#: the word that pins a group to no word: it takes the rest of the prompt (``proctex parts --assign 3=rest``)
REST = "rest"
#: a word the user gives a group: letters, then letters, spaces, hyphens or apostrophes, at most 48
_ASSIGNED_WORD = re.compile(r"^[a-z][a-z' -]{0,47}$")


def check_assignment(assigned: Any, groups: int | None = None) -> dict[int, str]:
    """The user's word per group, checked: ``{group index (int or decimal string): word}`` ->
    ``{int: word}`` with each word lower-cased and trimmed. A word is a part word of the vocabulary
    in any form ("legs", "table top"), a part noun it does not know ("antenna": a clause naming it
    goes to that group) or :data:`REST` (the group takes no word: the rest of the prompt). At most
    ``MAX_GROUPS`` entries; with ``groups`` given, every index must be below it. ``ValueError``
    naming the bad entry otherwise."""
    if assigned is None:
        return {}
    if not isinstance(assigned, dict):
        raise ValueError(f"part words must be an object {{group index: word}}, got {type(assigned).__name__}")
    if len(assigned) > MAX_GROUPS:
        raise ValueError(f"at most {MAX_GROUPS} part words, got {len(assigned)}")
    out: dict[int, str] = {}
    for key, word in assigned.items():
        k = str(key)
        if isinstance(key, bool) or not (isinstance(key, int) or (k.isdigit() and k.isascii() and len(k) <= 6)):
            raise ValueError(f"part words are keyed by group index, got {str(key)[:40]!r}")
        gid = int(k)
        if gid < 0 or (groups is not None and gid >= groups):
            raise ValueError(f"no group {gid}: the shape has groups 0 to {groups - 1 if groups else -1}")
        if not isinstance(word, str):
            raise ValueError(f"the part word for group {gid} must be a string, got {type(word).__name__}")
        w = " ".join(word.lower().split())
        if not _ASSIGNED_WORD.match(w):
            raise ValueError(f"the part word for group {gid} must be a word of letters (at most 48 characters), got {word[:60]!r}")
        out[gid] = w
    return out


def describe_groups(vertices: np.ndarray, faces: np.ndarray, grouping: Any, up: str | int = "z") -> list[V.Evidence]:
    """One :class:`.partvocab.Evidence` per non-degenerate group of ``grouping`` (a
    :class:`proctex.geometry.parts.Grouping`) on the mesh ``vertices (n, 3) float``, ``faces (m, 3)
    int``; ``up`` is "x", "y", "z" or an axis index."""
    u = "xyz".index(up) if isinstance(up, str) and up in ("x", "y", "z") else up
    if not isinstance(u, (int, np.integer)) or isinstance(u, bool) or u not in (0, 1, 2):
        raise ValueError(f"up must be x, y or z, got {up!r}")
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or not len(v):
        raise ValueError(f"vertices must be (n, 3) with n > 0, got {v.shape}")
    if not np.isfinite(v).all():
        raise ValueError("vertices must be finite")
    return V.evidence(v, grouping, int(u), max_groups=MAX_GROUPS)


#: Words of one kind: what holds a shape up. A group the prompt does not name that passes the test of
#: one of them takes the clause of another the prompt placed ("dark walnut legs" paints a chair's disc
#: base and its stretchers), before the rest of the prompt or the most alike shape.
KINDRED: tuple[tuple[str, ...], ...] = (("legs", "base", "rungs"),)


def part_word(form: str) -> str | None:
    """The canonical word of ``form`` ("legs" for "leg", "feet"; "top" for "table top"; None when not a part word)."""
    return V.word_of(form)


@lru_cache(maxsize=4096)
def _material_word(word: str) -> bool:
    """Whether the prompt parser reads ``word`` as a colour, material or pattern ("oak", "red")."""
    return bool(parse_prompt(word).understood)


def label_hits(token: str, labels: list[str]) -> list[str]:
    """The labels (several words each, as a node tree names parts: "Left Arm", "Back Rest") that
    ``token`` names: one of a label's words up to a plural (:func:`.names.same_word`),
    or, for a part word, one of its forms ("feet" names "Legs"). Qualifiers ("left", "front"),
    words that name no part and colour or material words ("Oak" of "Oak Panel": "oak" in a prompt is
    a material) are never matched."""
    token = token.lower()
    if _material_word(token):
        return []
    word = part_word(token)
    forms = (token,) + (PART_WORDS[word] if word else ())
    out = []
    for lab in dict.fromkeys(labels):
        if any(same_word(f, w) for w in matchable_words(lab) if not _material_word(w) for f in forms if "-" not in f):
            out.append(lab)
    return out


@dataclass
class Resolved:
    """What :func:`resolve_words` found: ``words`` word -> (group ids, why), ``scores`` group ->
    the score its word gave it, ``ties`` (group, word, rival word) where two words scored a group
    within :data:`TIE`, ``weak`` words whose best group scored under 0.5."""

    words: dict[str, tuple[list[int], str]]
    scores: dict[int, float] = field(default_factory=dict)
    ties: list[tuple[int, str, str]] = field(default_factory=list)
    weak: list[str] = field(default_factory=list)


def resolve_words(words: list[str], geoms: list[V.Evidence], kind: str | None = None, detail: bool = False, fixed: dict[int, str] | None = None):
    """Groups each canonical word of ``words`` takes, jointly: ``{word: (group ids, why)}`` (words
    no group passes are left out; ``detail=True`` returns a :class:`Resolved`). Every word gets its
    best group and a group its best word in one assignment problem over the scores (a group passing
    two words goes to the word it fits more, and "seat and legs" never share a group); then each
    group left joins the word that scores it best, when that score is at least
    :data:`EXTEND_SCORE` and :data:`EXTEND_SHARE` of the word's best group's score. ``fixed``:
    groups the user gave a word (``{group: word}``, :func:`check_assignment`): out of the
    assignment, and each joins its word (score 1) when that word is one of ``words``."""
    words = list(dict.fromkeys(words))
    for w in words:
        if w not in V.WORDS:
            raise ValueError(f"unknown part word {w!r}; known: {', '.join(V.WORDS)}")
    res = Resolved({})
    fixed = {int(g): (part_word(w) or w) for g, w in (fixed or {}).items()}
    pinned = [(g, w) for g, w in sorted(fixed.items()) if w in words]
    for g, w in pinned:
        res.words.setdefault(w, ([], "given by hand"))[0].append(g)
        res.scores[g] = 1.0
    if not words or not geoms:
        return res if detail else res.words
    scored = [[V.score(w, e, geoms, kind) if e.group not in fixed else (0.0, "") for e in geoms] for w in words]
    S = np.array([[s for s, _ in row] for row in scored])
    rows, cols = linear_sum_assignment(-S)
    owner: dict[int, int] = {}
    for i, j in zip(rows, cols):
        if S[i, j] >= MIN_SCORE:
            owner[j] = i
    best = {i: S[i, j] for j, i in owner.items()}
    for j in range(len(geoms)):
        if j in owner:
            continue
        i = int(np.argmax(S[:, j]))
        if i in best and S[i, j] >= EXTEND_SCORE and S[i, j] >= EXTEND_SHARE * best[i]:
            owner[j] = i
    for j, i in sorted(owner.items(), key=lambda x: geoms[x[0]].group):
        gid = geoms[j].group
        got = res.words.setdefault(words[i], ([], scored[i][j][1]))
        if got[1] == "given by hand":  # the word's own groups come first, those given by hand beside them
            res.words[words[i]] = got = (got[0], scored[i][j][1] + "; and group(s) given by hand")
        got[0].append(gid)
        res.scores[gid] = float(S[i, j])
        rival = [k for k in range(len(words)) if k != i and S[k, j] >= MIN_SCORE and S[i, j] - S[k, j] <= TIE]
        res.ties += [(gid, words[i], words[k]) for k in rival]
    res.weak = [words[i] for i, s in best.items() if s < 0.5 and not any(w == words[i] for _, w in pinned)]
    res.words = {w: (sorted(gids), why) for w, (gids, why) in res.words.items()}
    return res if detail else res.words


def groups_of_word(form: str, prompt: str, vertices: np.ndarray, faces: np.ndarray, grouping: Any, up: str | int = "z", assigned: dict[int, str] | None = None) -> list[int]:
    """The groups the part word ``form`` ("legs", "table top") takes on a shape, read for the kind of
    object ``prompt`` names (:func:`.partvocab.kind_of`); [] when it is no part word or no group
    passes it. ``assigned``: the user's words per group (:func:`check_assignment`), which win: a
    group given ``form``'s word is among them, a group given another word never."""
    word = part_word(form)
    fixed = check_assignment(assigned, len(grouping.groups))
    live = [g for g in grouping.groups if not g.degenerate]
    if word is None:
        key = " ".join(str(form).lower().split())
        return sorted(g for g, w in fixed.items() if w == key)
    if len(live) < 2:
        return sorted(g for g, w in fixed.items() if part_word(w) == word)
    tokens = V.join_compounds(re.findall(r"[\w'-]+", f"{prompt} {form}".lower()))
    got = resolve_words([word], describe_groups(vertices, faces, grouping, up), V.kind_of(tokens, _material_word), fixed=fixed)
    return list(got.get(word, ([], ""))[0])


# ------------------------------------------------------------------------------------------- plan
@dataclass
class PartPlan:
    """A prompt resolved against one shape's part groups.

    Attributes:
        prompt: the prompt as given.
        regions: the :class:`RegionPlan` of the prompt with the part words as part names.
        texts: group id -> the text that group is painted with, in the group's own frame, for groups
            that do not take the rest of the prompt (a clause naming the group, a guess for a clause
            whose part word is unknown, or a borrowed clause).
        words: canonical word -> group ids it took.
        kind: the kind of object the words were read for (:mod:`.partvocab`), or None.
        scores: group id -> the score of the word that took it (1: every condition met).
        guesses: group id -> the unknown part word whose clause it took as a guess.
        assigned: group id -> the word the user gave it (:func:`check_assignment`), which beat the
            scores and the labels.
        routes: group id -> how it got its text: "hand" (a word given by hand), "label", "word" (a
            part word's test), "guess", "kin" (a word of the same kind as a placed one), "alike" (the
            clause of the group most alike in shape); groups missing take the rest of the prompt.
        notes: human-readable lines: which groups each word took, with what score and why, ties,
            guesses, borrowed clauses, and clauses that could not be placed.
    """

    prompt: str
    regions: RegionPlan
    texts: dict[int, str] = field(default_factory=dict)
    words: dict[str, list[int]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    kind: str | None = None
    scores: dict[int, float] = field(default_factory=dict)
    guesses: dict[int, str] = field(default_factory=dict)
    assigned: dict[int, str] = field(default_factory=dict)
    routes: dict[int, str] = field(default_factory=dict)

    def text_for(self, group: int) -> str:
        """What group ``group`` is painted with: its clause, else the whole prompt."""
        return self.texts.get(group, self.prompt)

    def painted_text(self, group: int) -> str:
        """The text a surface painter paints ``group`` with: its clause, else the rest of the prompt
        (the whole prompt when it names no part or region)."""
        return self.texts.get(group, self.regions.base if self.regions.has_regions else self.prompt)


def _understood(text: str) -> bool:
    return bool(text.strip()) and bool(parse_prompt(text).understood)


def _shape_key(g: GroupGeometry) -> np.ndarray:
    """Slab or bar: the log ratios of one member's principal extents to its longest, the middle one
    (flat panels near 1, bars small) weighing four times the thinnest."""
    e = np.maximum(np.asarray(g.axes, dtype=float)[::-1], 1e-6)
    return np.log(e[:2] / e[2]) * np.array([0.25, 1.0])


_CUTS = {",", ";", ":", "with", "and", "having", "featuring", "plus"}
_ARTICLES = {"a", "an", "the", "its", "their", "some"}
_OF = {"in", "of", "made", "from"}


def unknown_part_nouns(tokens: list[str]) -> list[str]:
    """The part nouns of a prompt that the vocabulary does not know: the last word of a clause (cut
    at commas, "with", "and", ...) that the prompt parser does not read, that is neither a part
    word, an object noun nor a region word (:mod:`.regions`), and that follows a word the parser
    reads ("a gold *antenna*"), in a clause that names no object and no "in"/"of"/"made" (the
    object's own material: "a cabinet in red lacquer")."""
    from .regions import REGION_WORDS

    out: list[str] = []
    clause: list[str] = []
    for tok in [*tokens, ","]:
        if tok in _CUTS:
            words = [w for w in clause if w not in _ARTICLES]
            clause = []
            if len(words) < 2:
                continue
            last = words[-1]
            if not re.fullmatch(r"[a-z][a-z'-]*", last) or part_word(last) or last in V.NOUNS or last in REGION_WORDS or _material_word(last) or not any(_material_word(w) for w in words[:-1]):
                continue
            if any(w in V.NOUNS or w in _OF for w in words[:-1]):  # "a cabinet in red lacquer": the object's own material
                continue
            out.append(last)
        else:
            clause.append(tok)
    return list(dict.fromkeys(out))


def plan_parts(prompt: str, vertices: np.ndarray, faces: np.ndarray, grouping: Any, up: str | int = "z", assigned: dict[Any, str] | None = None) -> PartPlan:
    """Resolve ``prompt`` against the part groups of a mesh (module docstring).

    Args:
        prompt: any string (``ValueError`` otherwise).
        vertices, faces: the shape (``(n, 3)`` float, ``(m, 3)`` int).
        grouping: its :class:`proctex.geometry.parts.Grouping` (labels, where present, come first).
        up: the shape's up axis.
        assigned: the user's last word, ``{group index: word}`` (:func:`check_assignment`): a group
            given a word takes that word's clause whatever the scores and labels say (and no other
            word's); a group given :data:`REST` takes no word.
    Returns:
        :class:`PartPlan`.
    """
    if not isinstance(prompt, str):
        raise ValueError(f"prompt must be a string, got {type(prompt).__name__}")
    fixed = check_assignment(assigned, len(grouping.groups))
    labels = [g.label for g in grouping.groups if g.label]
    label_map = {lab.lower(): lab for lab in labels}
    text = V.join_compounds_text(prompt)  # "table top" -> "table-top"; the rest as written
    tokens = re.findall(r"#[0-9a-fA-F]{3,6}\b|[\w'-]+|[,;:]", text.lower())
    # A word naming a word of a group's label ("arms" for "Left Arm", "feet" for "Legs": a form of the
    # same part word) routes by the label: labels beat geometry.
    by_word = {t: hit for t in dict.fromkeys(tokens) if _label_of(t, label_map) is None and (hit := label_hits(t, labels))}
    free = [t for t in tokens if _label_of(t, label_map) is None and t not in by_word]
    wanted = list(dict.fromkeys(part_word(t) for t in free if part_word(t)))
    unknown = unknown_part_nouns(free)
    kind = V.kind_of(tokens, _material_word)
    live = [g for g in grouping.groups if not g.degenerate]
    # A word only becomes a part where the shape has more than one group: on a one-part vase "top"
    # and "base" stay regions of that part.
    geoms = describe_groups(vertices, faces, grouping, up) if (wanted or unknown) and len(live) > 1 else []
    res = resolve_words(wanted, geoms if len(geoms) > 1 else [], kind, detail=True, fixed=fixed)
    named = {lab for t in tokens for lab in ([_label_of(t, label_map)] if _label_of(t, label_map) else by_word.get(t, []))}
    if named:  # a group the prompt names by its label is not also taken by a word's geometric test
        taken = {g.index for g in grouping.groups if g.label in named and g.index not in fixed}
        res.words = {w: (kept, why) for w, (gids, why) in res.words.items() if (kept := [g for g in gids if g not in taken])}
    else:
        taken = set()
    # a part noun the vocabulary does not know but the user gave a group ("antenna") names that group
    by_hand = {w: sorted(g for g, x in fixed.items() if x == w) for w in dict.fromkeys(fixed.values()) if part_word(w) is None}
    parts_named = len(geoms) > 1 or bool(res.words) or any(w in by_hand for w in unknown)
    # the words' forms name parts; a word no group passes stays a region word where it is one ("a
    # dark wood handle" on a one-piece fork: the region along its axis)
    from .regions import REGION_WORDS

    forms = [f for w in wanted for f in PART_WORDS[w] if w in res.words or f not in REGION_WORDS] if parts_named else []
    regions = split_regions(text, labels + list(by_word) + forms + (unknown if parts_named else []))
    plan = PartPlan(
        prompt,
        regions,
        words={w: gids for w, (gids, _) in res.words.items()},
        kind=kind,
        scores={g: round(s, 3) for g, s in res.scores.items() if any(g in gids for gids, _ in res.words.values())},
        assigned=dict(fixed),
    )
    for gid, w in sorted(fixed.items()):
        plan.notes.append(f"group {gid} was given {w!r} by hand" + (": it takes the rest of the prompt" if w == REST else ""))
    if kind and wanted:
        plan.notes.append(f"part words read for {kind}" + (" (the object noun)" if any(t in V.NOUNS and not _material_word(t) for t in tokens) else " (the words the prompt uses)"))
    label_groups: dict[str, list[int]] = {}
    for g in grouping.groups:
        if g.label:
            label_groups.setdefault(g.label, []).append(g.index)
    clause_of: dict[int, str] = {}
    guesses: list[tuple[str, str]] = []
    for name, clause in regions.parts:
        if name in by_hand:
            gids = by_hand[name]
        elif name in label_groups or name in by_word:  # routed by the labels; groups given the word by hand beside them
            labs = [name] if name in label_groups else by_word[name]
            gids = sorted(
                {gid for lab in labs for gid in label_groups.get(lab, []) if gid not in fixed}
                | {g for g, w in fixed.items() if w == name or (part_word(name) is not None and part_word(w) == part_word(name))}
            )
            if name not in label_groups:
                plan.notes.append(f"{name!r} names the group(s) labelled {', '.join(repr(lab) for lab in labs)}: {', '.join(map(str, gids))}")
        elif part_word(name):
            word = part_word(name)
            gids = res.words.get(word, ([], ""))[0]
            if not gids:
                plan.notes.append(f"{clause!r} ({name!r}) paints nothing: no part of this shape passes the test of {word!r} ({V.score(word, geoms[0], geoms, kind)[1] if geoms else 'no groups'})")
        else:
            guesses.append((name, clause))
            continue
        route = "hand" if name in by_hand else "label" if (name in label_groups or name in by_word) else "word"
        for gid in gids:
            if gid not in clause_of:
                clause_of[gid] = clause
                plan.routes[gid] = "hand" if gid in fixed else route
    for word, (gids, why) in res.words.items():
        if any(gid in clause_of for gid in gids):
            sc = ", ".join(f"{g} ({plan.scores.get(g, 0):.2f})" for g in gids)
            plan.notes.append(f"{word!r} took group(s) {sc}: {why}" + (" (a weak match)" if word in res.weak else ""))
    for gid, word, rival in res.ties:
        plan.notes.append(f"group {gid}: {word!r} and {rival!r} scored it alike; it went to {word!r}")
    for word in wanted:
        if word not in res.words and not any(part_word(n) == word for n, _ in regions.parts):
            plan.notes.append(f"{word!r}: no part of this shape passes its test")
    # A clause whose part word is unknown: a weak match, the largest group no word took.
    area = {e.group: e.area_share for e in geoms}
    for name, clause in guesses:
        free_groups = [g.index for g in live if g.index not in clause_of and g.index not in taken and g.index in area and g.index not in fixed]
        if not free_groups:
            plan.notes.append(f"{clause!r} ({name!r}, a part word ProcTex does not know) paints nothing: every group is taken")
            continue
        gid = max(free_groups, key=lambda g: (area[g], -g))
        clause_of[gid] = clause
        plan.guesses[gid] = name
        plan.routes[gid] = "guess"
        plan.notes.append(f"{name!r} is a part word ProcTex does not know: its clause {clause!r} goes to group {gid}, the largest no other word took (a guess)")
    for t in regions.unplaced:
        plan.notes.append(f"clause {t!r} named no part of this shape; it paints nothing")
    plan.texts.update(clause_of)
    rest = regions.base
    others = [g for g in live if g.index not in clause_of]
    kin = _kindred_texts([g for g in others if g.index not in fixed], plan.words, clause_of, geoms or describe_groups(vertices, faces, grouping, up)) if clause_of and others else {}
    for gid, (text_, word, kind_word) in kin.items():
        plan.texts[gid] = text_
        plan.routes[gid] = "kin"
        plan.notes.append(f"group {gid} passes the test of {kind_word!r} and takes the clause of {word!r}, of the same kind: {text_!r}")
    others = [g for g in others if g.index not in kin]
    if not _understood(rest) and clause_of and others and not regions.regions:
        # The rest of the shape takes the rest of the prompt when it names a material, else the
        # clause of the group most alike in shape.
        key = {g.group: _shape_key(g) for g in (geoms or describe_groups(vertices, faces, grouping, up))}
        for g in others:
            if g.index not in key:
                continue
            near = min(clause_of, key=lambda c: (float(np.abs(key[g.index] - key[c]).sum()) if c in key else np.inf, c))
            plan.texts[g.index] = clause_of[near]
            plan.routes[g.index] = "alike"
            plan.notes.append(f"group {g.index} is named by no clause and the rest of the prompt names no material: it takes {clause_of[near]!r} from group {near}, the most alike in shape")
    return plan


def _kindred_texts(others: list[Any], words: dict[str, list[int]], clause_of: dict[int, str], geoms: list[GroupGeometry]) -> dict[int, tuple[str, str, str]]:
    """``{group: (text, placed word, kindred word it passes)}`` for the groups of ``others`` that
    pass the test of a :data:`KINDRED` word whose kin the plan placed (``words``, ``clause_of``)."""
    by_id = {g.group: g for g in geoms}
    out: dict[int, tuple[str, str, str]] = {}
    for kin in KINDRED:
        placed = [w for w in kin if any(gid in clause_of for gid in words.get(w, []))]
        if not placed:
            continue
        word = placed[0]
        text = clause_of[next(gid for gid in words[word] if gid in clause_of)]
        for g in others:
            geo = by_id.get(g.index)
            if geo is None or g.index in out:
                continue
            for k in kin:
                if k not in placed and V.score(k, geo, geoms, None)[0] >= 0.5:
                    out[g.index] = (text, word, k)
                    break
    return out


def new_part_texts(prompt: str, shape: Any, segmentation: Any, parts: list[int], up: str | int = "z") -> dict[int, str]:
    """What parts of a new shape that match no template group are painted with: the prompt resolved
    on the new shape itself (its parts grouped by kind, :func:`proctex.geometry.parts.kind_groups`),
    so "brass arms" paints arms the template lacked; ``{part: text}`` for the parts a clause (or a
    borrowed clause, or the rest joined by an unplaced clause) names, the others take the whole
    prompt's rest."""
    from proctex.geometry.parts import kind_groups

    if not parts:
        return {}
    grouping = kind_groups(shape, segmentation)
    plan = plan_parts(prompt, shape.vertices, shape.faces, grouping, up)
    out = {}
    for p in parts:
        g = int(grouping.part_group[p])
        if g in plan.texts:
            out[int(p)] = plan.texts[g]
    return out


# ----------------------------------------------------------------------------------------- report
def evidence_summary(e: V.Evidence, all_: list[V.Evidence]) -> dict[str, Any]:
    """The evidence of one group as a person reads it (JSON-ready): ``members``, ``area_share``,
    ``rank`` (0: the largest), ``height`` [low, high] in the shape's height (0 floor, 1 top),
    ``form`` (bar, plate or blob, with ``upright`` / ``lying``), ``rests_on`` and ``holds`` (group
    ids), ``corners`` (its members sit at the corners, 0-1), ``mirrored`` (a pair across the shape,
    0-1), ``outside`` (sticks out of the main mass, 0-1)."""
    forms = {"bar": V.bar(e), "plate": V.plate(e), "blob": V.blob(e)}
    form = max(forms, key=lambda k: forms[k]) if max(forms.values()) > 0.3 else "irregular"
    if form == "bar":
        form = ("upright " if e.long_up >= 0.8 else "lying " if e.long_up <= 0.45 else "slanted ") + form
    elif form == "plate":
        form = ("lying " if e.thin_up >= 0.8 else "upright " if e.thin_up <= 0.45 else "slanted ") + form
    return {
        "members": int(e.members),
        "area_share": round(float(e.area_share), 4),
        "rank": int(e.rank),
        "height": [round(e.u_lo, 3), round(e.u_hi, 3)],
        "form": form,
        "rests_on": [int(g) for g in e.rests_on],
        "holds": [int(g) for g in e.holds],
        "corners": round(float(e.corners()), 3),
        "mirrored": round(float(V.mirrored(e, all_)), 3),
        "outside": round(float(V.outside_main(e, all_)), 3),
    }


def parts_report(prompt: str, vertices: np.ndarray, faces: np.ndarray, grouping: Any, up: str | int = "z", assigned: dict[Any, str] | None = None) -> dict[str, Any]:
    """What the prompt's part words do on this shape, per group (JSON-ready; ``proctex parts FAMILY``,
    the studio's part panel): ``prompt``, ``kind``, ``assigned`` (the user's words), ``clauses``
    (the prompt's clauses naming parts: ``name`` as written, its ``word``, its ``text``) and ``notes``
    (:attr:`PartPlan.notes`), and per group of ``grouping``: ``group``, ``label``, ``degenerate``,
    ``word`` (the word that took it: a part word, a guessed unknown noun, a word given by hand, or
    None), ``how`` ("label", "word", "hand", "guess", "kin": the clause of a word of its kind, "alike":
    the clause of the group most alike in shape, "rest": the rest of the prompt), ``text`` (what it
    is painted with), ``score`` (the word's score, 0-1, None where no word scored it), ``rival`` (the
    prompt's next-best word and its score), ``looks_like`` (the vocabulary's best words for it,
    whatever the prompt says, with scores) and ``evidence`` (:func:`evidence_summary`)."""
    fixed = check_assignment(assigned, len(grouping.groups))
    plan = plan_parts(prompt, vertices, faces, grouping, up, assigned=fixed)
    live = [g for g in grouping.groups if not g.degenerate]
    geoms = describe_groups(vertices, faces, grouping, up) if len(live) > 1 else []
    ev = {e.group: e for e in geoms}
    word_of_group = {g: w for w, gids in plan.words.items() for g in gids}
    tokens = V.join_compounds(re.findall(r"[\w'-]+", V.join_compounds_text(prompt).lower()))
    in_prompt = list(dict.fromkeys(w for t in tokens if (w := part_word(t))))
    kind = plan.kind
    vocab = list(V.WORD_KINDS[kind]) if kind in V.WORD_KINDS else list(V.WORDS)
    rows = []
    for g in grouping.groups:
        gid = g.index
        how = plan.routes.get(gid, "rest")
        word = {"hand": fixed.get(gid), "guess": plan.guesses.get(gid), "word": word_of_group.get(gid), "label": g.label}.get(how)
        row: dict[str, Any] = {
            "group": gid,
            "label": g.label or "",
            "degenerate": bool(g.degenerate),
            "word": word or None,
            "how": how,
            "text": plan.painted_text(gid),
            "score": plan.scores.get(gid) if how in ("word", "hand") else None,
            "rival": None,
            "looks_like": [],
            "evidence": None,
        }
        if gid in fixed:  # the user's word, whether or not the prompt names it (its text says what it took)
            row.update(word=fixed[gid], how="hand", score=1.0)
        e = ev.get(gid)
        if e is not None:
            row["evidence"] = evidence_summary(e, geoms)
            scores = sorted(((V.score(w, e, geoms, kind)[0], w) for w in vocab), reverse=True)
            row["looks_like"] = [[w, round(s, 3)] for s, w in scores[:3] if s > 0]
            others = [(s, w) for s, w in ((V.score(w, e, geoms, kind)[0], w) for w in in_prompt) if w not in (row["word"], part_word(row["word"] or "")) and s > 0]
            if others:
                s, w = max(others)
                row["rival"] = [w, round(s, 3)]
        rows.append(row)
    clauses = [{"name": name, "word": part_word(name) or name, "text": text} for name, text in plan.regions.parts]
    return {"prompt": prompt, "kind": kind, "assigned": {str(k): v for k, v in sorted(fixed.items())}, "clauses": clauses, "groups": rows, "notes": list(plan.notes)}
