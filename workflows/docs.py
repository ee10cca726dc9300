"""The configuration reference (``docs/configuration.md``), generated from the build config's
dataclasses so that it cannot drift from the code: ``python -m workflows.docs`` prints it,
``python -m workflows.docs --out docs/configuration.md`` (``make docs``) writes it.

Every setting is read from the classes themselves: the fields (:func:`dataclasses.fields`), their
types and defaults (``default`` or ``default_factory()``), and their help from, in this order, the
class docstring's ``Attributes:`` block (entries such as ``n_train, n_test: ...``, ``w_*: ...`` or
``iterations: ...; lr: ...``), ``field(metadata={"help": ...})``, a ``#:`` comment above the field
or a comment after it, and a parenthesis after the field's name in the docstring's summary
(``model`` (built-in name)). A field whose value is a dataclass (by default, or once the root's
``validate()`` has filled it in) is a section of its own: a TOML table named after the field.
The output depends on nothing but the code, so it is the same on every run and machine.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import fnmatch
import inspect
import io
import json
import math
import os
import re
import sys
import textwrap
import tokenize
import typing
from typing import Any

HEADER = "<!-- Generated from the build config's dataclasses by `make docs` (`python -m workflows.docs`). Do not edit by hand: change the docstrings and run `make docs`. -->"
_NAME = r"(?:``)?[A-Za-z_][\w*]*(?:``)?"
_NAMES = rf"{_NAME}(?:\s*,\s*{_NAME})*"
_ENTRY = re.compile(rf"^({_NAMES})\s*:\s+(.*)$", re.DOTALL)


# --------------------------------------------------------------------------------------- helpers
def _rst_to_md(text: str) -> str:
    """Docstring markup as Markdown: ``x`` and :role:`x` become `x`; whitespace is collapsed."""
    text = re.sub(r":[a-z]+:`~?([^`]+)`", r"`\1`", text)
    text = re.sub(r"``(.+?)``", r"`\1`", text, flags=re.DOTALL)
    return re.sub(r"\s+", " ", text).strip()


def _cell(text: str) -> str:
    """Text for a Markdown table cell."""
    return text.replace("|", "\\|") if text else ""


def _type_name(tp: Any) -> str:
    if isinstance(tp, str):
        return tp
    if isinstance(tp, type) and not typing.get_args(tp):
        return tp.__name__
    return str(tp).replace("typing.", "")


def _toml(value: Any) -> str:
    """``value`` as a TOML value (inline tables and arrays for containers)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, dict):
        if not value:
            return "{}"
        return "{ " + ", ".join(f"{_toml_key(str(k))} = {_toml(v)}" for k, v in value.items()) + " }"
    raise TypeError(f"no TOML form for {type(value).__name__}")


def _toml_key(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else json.dumps(key)


def _default(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:  # type: ignore[misc]
        return f.default_factory()  # type: ignore[misc]
    return dataclasses.MISSING


# ------------------------------------------------------------------------------------ field help
def _docstring_parts(cls: type) -> tuple[str, list[str], str]:
    """The class docstring as (summary, lines of its ``Attributes:`` block, what follows the block)."""
    doc = inspect.getdoc(cls) or ""
    if not doc or doc.startswith(f"{cls.__name__}("):  # none, or the signature dataclass() writes
        return "", [], ""
    lines = doc.splitlines()
    for i, line in enumerate(lines):
        if line.strip() == "Attributes:":
            indent = len(line) - len(line.lstrip())
            j = i + 1
            while j < len(lines) and (not lines[j].strip() or len(lines[j]) - len(lines[j].lstrip()) > indent):
                j += 1
            return "\n".join(lines[:i]).strip(), lines[i + 1 : j], "\n".join(lines[j:]).strip()
    return doc.strip(), [], ""


def _split_names(names: str) -> list[str]:
    return [n.strip().strip("`") for n in names.split(",")]


def _attribute_help(cls: type, field_names: list[str]) -> dict[str, str]:
    """Help per field from the ``Attributes:`` block: ``a, b: text`` gives both the text;
    ``w_*: text`` gives every field it matches that has no entry of its own; inside an entry,
    ``; name: text`` and ``. name: text`` start the entry of another field."""
    _, block, _ = _docstring_parts(cls)
    if not block:
        return {}
    indent = min(len(line) - len(line.lstrip()) for line in block if line.strip())
    entries: list[str] = []
    for line in block:
        if not line.strip():
            continue
        if len(line) - len(line.lstrip()) == indent:
            entries.append(line.strip())
        elif entries:
            entries[-1] += " " + line.strip()
    known = set(field_names)

    def is_field(name: str) -> bool:
        return name in known or ("*" in name and any(fnmatch.fnmatchcase(k, name) for k in known))

    sub_entry = re.compile(rf"(?<=[;.])\s+({_NAMES})\s*:\s+")
    pieces: list[tuple[list[str], str]] = []
    for entry in entries:
        m = _ENTRY.match(entry)
        if not m or not all(is_field(n) for n in _split_names(m.group(1))):
            continue
        names, text, start = _split_names(m.group(1)), m.group(2), 0
        for sm in sub_entry.finditer(text):  # "...; lr: ..." or "... sample. symmetry: ..."
            if all(is_field(n) for n in _split_names(sm.group(1))):
                pieces.append((names, text[start : sm.start()]))
                names, start = _split_names(sm.group(1)), sm.end()
        pieces.append((names, text[start:]))
    out: dict[str, str] = {}
    patterns: list[tuple[str, str]] = []
    for names, text in pieces:
        text = _rst_to_md(text).rstrip(";")
        for name in names:
            if "*" in name:
                patterns.append((name, text))
            else:
                out.setdefault(name, text)
    for pattern, text in patterns:
        for name in field_names:
            if name not in out and fnmatch.fnmatchcase(name, pattern):
                out[name] = text
    return out


def _comment_help(cls: type) -> dict[str, str]:
    """Help per field from the class source: ``#:`` comment lines right above the field, else a
    comment after it on its last line."""
    try:
        lines, _ = inspect.getsourcelines(cls)
    except (OSError, TypeError):
        return {}
    source = textwrap.dedent("".join(lines))
    src_lines = source.splitlines()
    comments = {tok.start[0]: tok.string for tok in tokenize.generate_tokens(io.StringIO(source).readline) if tok.type == tokenize.COMMENT}
    out: dict[str, str] = {}
    for node in ast.parse(source).body[0].body:  # type: ignore[attr-defined]
        if not (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)):
            continue
        above: list[str] = []
        k = node.lineno - 1  # 1-based line above the field
        while k >= 1 and src_lines[k - 1].strip().startswith("#:"):
            above.insert(0, src_lines[k - 1].strip()[2:].strip())
            k -= 1
        after = comments.get(node.end_lineno or node.lineno, "")
        text = " ".join(above) or (after[1:].lstrip(":").strip() if after else "")
        if text:
            out[node.target.id] = _rst_to_md(text)
    return out


def _summary_help(cls: type, field_names: list[str]) -> dict[str, str]:
    """Help from the docstring's summary: the parenthesis right after ``name``."""
    summary, _, _ = _docstring_parts(cls)
    out: dict[str, str] = {}
    for name in field_names:
        m = re.search(rf"``{re.escape(name)}``\s*\(", summary)
        if not m:
            continue
        depth, i = 1, m.end()
        while i < len(summary) and depth:
            depth += {"(": 1, ")": -1}.get(summary[i], 0)
            i += 1
        out[name] = _rst_to_md(summary[m.end() : i - 1])
    return out


def field_help(cls: type) -> dict[str, str]:
    """Help text per field of the dataclass ``cls`` (see the module docstring for the sources)."""
    names = [f.name for f in dataclasses.fields(cls)]
    out = _attribute_help(cls, names)
    for f in dataclasses.fields(cls):
        meta = f.metadata.get("help") or f.metadata.get("doc")
        if f.name not in out and meta:
            out[f.name] = _rst_to_md(str(meta))
    for source in (_comment_help(cls), _summary_help(cls, names)):
        for name, text in source.items():
            out.setdefault(name, text)
    for name in names:  # named only inside another field's help: point there
        if name not in out:
            other = next((k for k in names if k in out and f"`{name}`" in out[k]), None)
            if other:
                out[name] = f"see `{other}`."
    return out


# --------------------------------------------------------------------------------------- walking
class _Unchecked:
    """A section standing in for a real one while the root's own ``validate()`` fills in the
    sections it defaults (their own checks want real sources, files and models)."""

    def __init__(self, real: Any) -> None:
        self._real = real

    def validate(self) -> _Unchecked:
        return self

    def __getattr__(self, name: str) -> Any:
        return getattr(self._real, name)


def _section_values(root_cls: type) -> dict[str, Any]:
    """The default value of each field of ``root_cls``, with the sections its ``validate()`` fills
    in (fields declared ``None`` that hold a dataclass once validated) resolved."""
    values = {}
    for f in dataclasses.fields(root_cls):
        values[f.name] = _default(f)
    if any(v is None for v in values.values()) and hasattr(root_cls, "validate"):
        probe = root_cls()
        for f in dataclasses.fields(root_cls):
            value = getattr(probe, f.name)
            if dataclasses.is_dataclass(value):
                setattr(probe, f.name, _Unchecked(value))
        try:
            probe.validate()
        except (ValueError, TypeError, AttributeError):
            return values
        for f in dataclasses.fields(root_cls):
            value = getattr(probe, f.name)
            if values[f.name] is None and dataclasses.is_dataclass(value) and not isinstance(value, type):
                values[f.name] = value
    return values


@dataclasses.dataclass
class Section:
    path: tuple[str, ...]  # () for the top level, ("source",), ("cage",), ...
    cls: type
    values: dict[str, Any]  # default per field (a dataclass instance for a sub-section)


def sections_of(root_cls: type) -> list[Section]:
    """The root and every nested dataclass, depth first, in field order."""
    out: list[Section] = []

    def walk(cls: type, path: tuple[str, ...], values: dict[str, Any]) -> None:
        out.append(Section(path, cls, values))
        for f in dataclasses.fields(cls):
            value = values[f.name]
            if dataclasses.is_dataclass(value) and not isinstance(value, type):
                sub = {g.name: getattr(value, g.name) for g in dataclasses.fields(value)}
                walk(type(value), path + (f.name,), sub)

    walk(root_cls, (), _section_values(root_cls))
    return out


def _is_section(value: Any) -> bool:
    return dataclasses.is_dataclass(value) and not isinstance(value, type)


def _first_sentence(text: str) -> str:
    """The first sentence of docstring text, as Markdown, ending in a full stop."""
    sentence = re.split(r"(?<=[.:])\s", _rst_to_md(text), maxsplit=1)[0]
    return sentence.rstrip(".:") + "."


def _table_name(path: tuple[str, ...]) -> str:
    return "[" + ".".join(path) + "]" if path else "top level"


def _slug(title: str) -> str:
    s = re.sub(r"[^\w\- ]", "", title.lower().replace("`", ""))
    return s.replace(" ", "-")


def _section_title(sec: Section) -> str:
    return f"`{_table_name(sec.path)}`: {sec.cls.__name__}" if sec.path else f"Top level: {sec.cls.__name__}"


# --------------------------------------------------------------------------------------- output
def config_reference() -> str:
    """The configuration reference in Markdown: the build config's sections (one TOML table each),
    every setting with its type, default and help, the older flat keys, the presets and a file
    with every setting at its default."""
    from proctex.store.config import BuildConfig

    module = sys.modules[BuildConfig.__module__]
    secs = sections_of(BuildConfig)
    root_summary, _, _ = _docstring_parts(BuildConfig)
    lines = [HEADER, "", "# Configuration reference", ""]
    lines += [
        (
            "A build config is a TOML or JSON file: `proctex build CONFIG --out STORE` (or `--config CONFIG`);"
            " the command's flags override it, and `--preset NAME` starts from a preset under both. The"
            f" file is read into `{BuildConfig.__module__}.{BuildConfig.__qualname__}`; each section below is a"
            " TOML table named after its field (a JSON object under the same key), and the top-level"
            " settings come before the first table. `family.json` in a family store keeps the resolved"
            " config in the same shape. A `generator` source names a generator file: see"
            " [Your own generator](cli.md#your-own-generator)."
        ),
        "",
        _rst_to_md(root_summary.split("\n\n")[0]),
        "",
    ]
    for meth in ("from_file", "read_settings", "from_dict"):
        fn = getattr(BuildConfig, meth, None)
        if fn is not None and fn.__doc__:
            lines += [f"- `{BuildConfig.__qualname__}.{meth}`: {_rst_to_md(inspect.getdoc(fn) or '')}"]
    lines += ["", "| table | class | what |", "|---|---|---|"]
    for sec in secs:
        summary, _, _ = _docstring_parts(sec.cls)
        what = _first_sentence(summary) if sec.path else "the family seed and settings of the whole build"
        anchor = _slug(_section_title(sec))
        lines.append(f"| [`{_cell(_table_name(sec.path))}`](#{anchor}) | `{sec.cls.__name__}` | {_cell(what)} |")
    lines.append("")

    for sec in secs:
        summary, _, notes = _docstring_parts(sec.cls)
        helps = field_help(sec.cls)
        lines += [f"## {_section_title(sec)}", "", f"Python: `{sec.cls.__module__}.{sec.cls.__qualname__}`.", ""]
        if sec.path and summary:
            lines += [_rst_to_md(summary), ""]
        lines += ["| setting | type | default | what |", "|---|---|---|---|"]
        for f in dataclasses.fields(sec.cls):
            value = sec.values[f.name]
            if _is_section(value):
                target = _section_title(Section(sec.path + (f.name,), type(value), {}))
                lines.append(f"| `{f.name}` | `{type(value).__name__}` | | the table [`{_table_name(sec.path + (f.name,))}`](#{_slug(target)}) |")
                continue
            default = "(required)" if value is dataclasses.MISSING else ("not set" if value is None else f"`{_toml(value)}`")
            lines.append(f"| `{f.name}` | `{_cell(_type_name(f.type))}` | {_cell(default)} | {_cell(helps.get(f.name, ''))} |")
        lines.append("")
        if notes:
            lines += [_rst_to_md(notes), ""]

    tables = {sec.path for sec in secs if sec.path}
    flat = getattr(module, "FLAT_KEYS", None)
    if flat:
        lines += [
            "## Older flat keys",
            "",
            ("Configs written before the sections existed put these keys at the top level; they are still read and land in the setting shown (`FLAT_KEYS`)."),
            "",
            "| flat key | setting |",
            "|---|---|",
        ]
        lines += [f"| `{k}` | `[{s}] {n}` |" for k, (s, n) in sorted(flat.items())]
        lines.append("")

    presets = getattr(module, "PRESETS", None)
    if presets:
        lines += ["## Presets", "", ("`--preset NAME` (or `from_dict(data, preset=NAME)`) starts from these settings; the file and the flags lay over them (`PRESETS`)."), ""]
        for name in sorted(presets):
            lines += [f"`{name}`:", "", "```toml", *_toml_document(presets[name], tables), "```", ""]

    lines += ["## Every setting at its default", "", ("A file with every setting at its default value (settings that are not set by default are comments; name exactly one source):"), "", "```toml"]
    lines += _toml_document(_defaults_tree(secs), tables)
    lines += ["```", ""]
    return "\n".join(lines)


def _defaults_tree(secs: list[Section]) -> dict[str, Any]:
    """The defaults as nested dicts (None where a setting is not set by default)."""
    tree: dict[str, Any] = {}
    for sec in secs:
        node = tree
        for key in sec.path:
            node = node.setdefault(key, {})
        for name, value in sec.values.items():
            if not _is_section(value):
                node[name] = None if value is dataclasses.MISSING else value
    return tree


def _toml_document(tree: dict[str, Any], tables: set[tuple[str, ...]], path: tuple[str, ...] = ()) -> list[str]:
    """``tree`` as TOML lines: its settings, then each of its sections (paths in ``tables``) as a
    table; a setting that is None is a comment."""
    lines: list[str] = []
    subs = []
    for k, v in tree.items():
        if path + (k,) in tables and isinstance(v, dict):
            subs.append((k, v))
        elif v is None:
            lines.append(f"# {_toml_key(k)} = ...  (not set)")
        else:
            lines.append(f"{_toml_key(k)} = {_toml(v)}")
    for k, v in subs:
        lines += ["", f"[{'.'.join(path + (k,))}]"]
        lines += _toml_document(v, tables, path + (k,))
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m workflows.docs", description="the configuration reference (Markdown)")
    parser.add_argument("--out", help="write it to this file (default: print it)")
    args = parser.parse_args(argv)
    text = config_reference()
    if args.out:
        tmp = f"{args.out}.tmp{os.getpid()}"
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, args.out)
        print(f"wrote {args.out}")
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
