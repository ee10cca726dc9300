"""The documentation stays true: the README is short and opens with the Quickstart, every
``proctex`` command line in the README and the guides parses with the real parser, every ``make``
target exists, every relative link lands on a file (and heading), and the configuration reference
is what ``make docs`` generates. The checkers are pure functions on strings, each shown to fail."""

from __future__ import annotations

import re
import shlex
import tomllib
import unicodedata
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
MAX_README_LINES = 300


def doc_files() -> list[Path]:
    return [README, *sorted((ROOT / "docs").glob("*.md"))]


def link_files() -> list[Path]:
    return [README, ROOT / "CHANGELOG.md", *sorted((ROOT / "docs").glob("*.md"))]


# ------------------------------------------------------------------------------------ markdown
FENCE = re.compile(r"^\s*(```+|~~~+)(.*)$")


def fenced_blocks(text: str) -> list[tuple[str, int, list[str]]]:
    """``(info string, first line number, lines)`` of every fenced code block."""
    blocks, lines = [], text.splitlines()
    i = 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        fence, info, body, j = m.group(1), m.group(2).strip(), [], i + 1
        while j < len(lines) and not lines[j].strip().startswith(fence):
            body.append(lines[j])
            j += 1
        blocks.append((info, i + 2, body))
        i = j + 1
    return blocks


def prose(text: str, code_spans: bool = True) -> str:
    """``text`` without fenced code blocks and (``code_spans``) inline code spans: their content is
    no link."""
    out, in_fence, fence = [], False, ""
    for line in text.splitlines():
        m = FENCE.match(line)
        if m and not in_fence:
            in_fence, fence = True, m.group(1)
            out.append("")
            continue
        if in_fence:
            if line.strip().startswith(fence):
                in_fence = False
            out.append("")
            continue
        out.append(re.sub(r"(`+)(?:(?!\1).)+?\1", "``", line) if code_spans else line)
    return "\n".join(out)


def command_lines(block: list[str]) -> list[tuple[int, str]]:
    """``(offset, line)`` of each logical line of a block: trailing backslashes joined."""
    out, buf, start = [], "", 0
    for k, line in enumerate(block):
        if not buf:
            start = k
        if line.rstrip().endswith("\\"):
            buf += line.rstrip()[:-1] + " "
            continue
        out.append((start, buf + line))
        buf = ""
    if buf:
        out.append((start, buf))
    return out


SHELL_STOPS = {"|", "||", "&&", ";", "&", ">", ">>", "<", "2>", "2>&1", "&>"}


def shell_words(line: str) -> list[str]:
    """The words of one shell command line: comments removed, cut at a pipe, a list operator or a
    redirection (what follows is the shell's business, not the command's)."""
    lexer = shlex.shlex(line, posix=True, punctuation_chars="|&;<>")
    lexer.whitespace_split = True
    lexer.commenters = "#"
    words = []
    for word in lexer:
        if word in SHELL_STOPS or re.fullmatch(r"\d?[<>|&;]+.*", word):
            break
        words.append(word)
    return words


def is_proctex(word: str) -> bool:
    return word == "proctex" or word.endswith("/proctex")


# ------------------------------------------------------------------------------------- checkers
def cli_parser():
    """The parser of the installed ``proctex`` command (``workflows.cli``: ``proctex.cli``'s
    commands plus ``serve``, ``screenshot`` and the Ray options)."""
    from workflows.cli import build_parser

    return build_parser()


def check_commands(text: str, where: str, parser, make_targets: set[str]) -> list[str]:
    """Problems with the command lines in ``text``'s fenced code blocks: a ``proctex`` line (also
    after ``$ `` or as ``.venv/bin/proctex``) the parser refuses, or a ``make`` target that the
    Makefile lacks."""
    problems = []
    for info, first, block in fenced_blocks(text):
        if info and info.split()[0] not in ("bash", "sh", "shell", "console", "text"):
            continue
        for offset, line in command_lines(block):
            head = line.split()[:2]
            if head[:1] == ["$"]:
                head = head[1:]
            if not head or not (is_proctex(head[0]) or head[0] == "make"):
                continue  # another program, or not a command at all (a diagram, a config)
            try:
                words = shell_words(line)
            except ValueError as exc:
                problems.append(f"{where}:{first + offset}: cannot split {line.strip()!r}: {exc}")
                continue
            if words and words[0] == "$":
                words = words[1:]
            if not words:
                continue
            if is_proctex(words[0]):
                try:
                    parser.parse_args(words[1:])
                except SystemExit as exc:
                    if exc.code not in (0, None):
                        problems.append(f"{where}:{first + offset}: the proctex parser refuses {line.strip()!r}")
            elif words[0] == "make":
                for target in words[1:]:
                    if target.startswith("-") or "=" in target:
                        continue
                    if target not in make_targets:
                        problems.append(f"{where}:{first + offset}: no make target {target!r} in the Makefile")
    return problems


def makefile_targets(text: str) -> set[str]:
    """The targets a Makefile defines (rules and ``.PHONY`` names; not variable assignments)."""
    targets = set()
    for line in text.splitlines():
        if line.startswith(("\t", "#", " ")):
            continue
        m = re.match(r"^([^:=#\s][^:=#]*?)\s*::?(?!=)", line)
        if m:
            names = m.group(1).split()
            if names == [".PHONY"]:
                targets.update(line.split(":", 1)[1].split())
            else:
                targets.update(n for n in names if "$" not in n)
    return targets


def github_slug(heading: str) -> str:
    """The anchor GitHub gives a heading: markup and punctuation dropped, lower case, spaces as
    hyphens."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # links: their text
    text = text.replace("`", "").replace("*", "").replace("~", "")
    text = re.sub(r"<[^>]+>", "", text).strip().lower()
    text = "".join(c for c in text if c in " -_" or unicodedata.category(c)[0] in "LN")
    return text.replace(" ", "-")


def anchors(text: str) -> set[str]:
    """Every heading anchor of a Markdown text (repeated headings get -1, -2, ... as on GitHub)."""
    seen: dict[str, int] = {}
    out = set()
    for line in prose(text, code_spans=False).splitlines():
        m = re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
        if not m:
            continue
        slug = github_slug(m.group(1))
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        out.add(slug if n == 0 else f"{slug}-{n}")
    return out


LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\[\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")


def check_links(text: str, path: Path, read=None) -> list[str]:
    """Problems with the relative links of a Markdown file at ``path``: a target file that does not
    exist, or an anchor no heading of the target has. Web and mail links are not followed.
    ``read(path)`` gives another file's text."""
    read = read or (lambda p: p.read_text(encoding="utf-8"))
    problems = []
    for lineno, line in enumerate(prose(text).splitlines(), 1):
        for m in LINK.finditer(line):
            target = m.group(1)
            if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.IGNORECASE):  # http:, https:, mailto:, ...
                continue
            file_part, _, anchor = target.partition("#")
            dest = (path.parent / file_part).resolve() if file_part else path
            if file_part and not dest.exists():
                problems.append(f"{path.name}:{lineno}: {target!r}: no file {dest}")
                continue
            if anchor:
                if dest.is_dir() or dest.suffix.lower() != ".md":
                    continue
                heads = anchors(text if dest == path else read(dest))
                if anchor.lower() not in heads:
                    problems.append(f"{path.name}:{lineno}: {target!r}: no heading #{anchor} in {dest.name}")
    return problems


# ---------------------------------------------------------------------------------------- tests
def quickstart_problems(text: str, max_lines: int = MAX_README_LINES) -> list[str]:
    """Problems with a README: longer than ``max_lines``; a first section other than the Quickstart;
    Quickstart code blocks whose commands are not exactly ``make demo`` and ``make test``, or that
    are not the README's first code block."""
    problems = []
    n = len(text.splitlines())
    if n > max_lines:
        problems.append(f"README.md has {n} lines (at most {max_lines}): move detail to docs/")
    sections = [line for line in prose(text).splitlines() if line.startswith("## ")]
    if not sections or sections[0] != "## Quickstart":
        problems.append(f"the README's first section is {sections[:1]}, not ## Quickstart")
        return problems
    head, quick = text.split("\n## Quickstart", 1)
    quick = quick.split("\n## ", 1)[0]
    if fenced_blocks(head):
        problems.append("a code block comes before the Quickstart's")
    commands = [" ".join(w) for _, block in [(i, b) for i, _, b in fenced_blocks(quick)] for _, line in command_lines(block) if (w := shell_words(line))]
    if commands != ["make demo", "make test"]:
        problems.append(f"the Quickstart's commands are {commands}, not make demo and make test")
    return problems


def test_readme_is_short_and_opens_with_the_quickstart():
    text = README.read_text(encoding="utf-8")
    problems = quickstart_problems(text)
    assert not problems, "\n".join(problems)
    quick = text.split("## Quickstart", 1)[1].split("\n## ", 1)[0]
    assert "torch==2.13.0" in quick and "make setup" in quick, "the Quickstart says how setup installs torch first"


def test_readme_keeps_the_test_count_and_todays_results():
    text = README.read_text(encoding="utf-8")
    assert re.search(r"[\d,]+ tests: (about )?\d+ minutes", text), "the Tests section states the test count and time"
    assert "## Results today" in text and "fidelity_baseline.py --table" in text and "make bench-fidelity" in text


@pytest.mark.parametrize("path", doc_files(), ids=lambda p: p.name)
def test_command_lines_parse(path):
    parser = cli_parser()
    targets = makefile_targets((ROOT / "Makefile").read_text(encoding="utf-8"))
    problems = check_commands(path.read_text(encoding="utf-8"), path.name, parser, targets)
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("path", link_files(), ids=lambda p: p.name)
def test_relative_links_resolve(path):
    problems = check_links(path.read_text(encoding="utf-8"), path)
    assert not problems, "\n".join(problems)


def config_reference_problems(stored: str, generated: str) -> list[str]:
    """A problem when the stored configuration reference is not the generated one."""
    if stored == generated:
        return []
    old, new = stored.splitlines(), generated.splitlines()
    first = next((i for i, (a, b) in enumerate(zip(old, new)) if a != b), min(len(old), len(new)))
    return [f"docs/configuration.md is out of date (first difference at line {first + 1}): run `make docs`"]


def test_configuration_reference_is_current():
    from workflows.docs import config_reference

    stored = (ROOT / "docs" / "configuration.md").read_text(encoding="utf-8")
    problems = config_reference_problems(stored, config_reference())
    assert not problems, "\n".join(problems)


def build_config_class():
    """The build config's root class (the one line of this file that names its module)."""
    from proctex.store.config import BuildConfig

    return BuildConfig


def test_configuration_reference_is_deterministic_and_complete():
    import dataclasses

    from workflows.docs import config_reference, sections_of

    text = config_reference()
    assert text == config_reference()
    BuildConfig = build_config_class()
    for sec in sections_of(BuildConfig):
        for f in dataclasses.fields(sec.cls):
            assert f"| `{f.name}` |" in text, f"{sec.cls.__name__}.{f.name} is missing from the reference"
    assert {sec.path for sec in sections_of(BuildConfig)} >= {(), ("source",), ("paint",), ("cage",), ("train",)}


def test_configuration_reference_defaults_are_a_valid_config():
    """The reference's file of defaults, read as the CLI reads a config, is accepted and resolves to
    exactly the defaults it shows (so its TOML tables are the sections the parser knows)."""
    from workflows.docs import config_reference

    BuildConfig = build_config_class()
    text = config_reference()
    block = next(body for info, _, body in fenced_blocks(text.split("## Every setting at its default", 1)[1]) if info == "toml")
    data = tomllib.loads("\n".join(block))
    data["source"]["model"] = "mug"
    config = BuildConfig.from_dict(data)
    resolved = config.to_dict()
    for section, values in data.items():
        if isinstance(values, dict):
            for key, value in values.items():
                assert resolved[section][key] == value, (section, key)
        else:
            assert resolved[section] == values, section


# ------------------------------------------------------------------------- the checkers can fail
BAD_DOC = """# A page

## Quickstart

```bash
make demo
.venv/bin/proctex bogus-command --out x
$ proctex transfer fam --out a.glb --no-such-flag | tee log
proctex build --model chair \\
    --out out/x --n-train notanumber
proctex models --json > models.json   # fine: the redirection is the shell's
make no-such-target
```

See [the guide](missing.md), [a heading](#no-such-heading), [ok](#a-page), [web](https://example.com/x.md)
and `[not a link](nowhere.md)`.
"""


def test_checkers_report_bad_commands_and_targets():
    problems = check_commands(BAD_DOC, "bad.md", cli_parser(), {"demo", "test"})
    text = "\n".join(problems)
    assert "bogus-command" in text
    assert "--no-such-flag" in text
    assert "notanumber" in text  # a continued line is checked as one command
    assert "no-such-target" in text
    assert "models --json" not in text and "'demo'" not in text
    assert len(problems) == 4, text


def test_checkers_report_dead_links_and_anchors(tmp_path):
    page = tmp_path / "page.md"
    page.write_text(BAD_DOC)
    problems = check_links(BAD_DOC, page)
    text = "\n".join(problems)
    assert "missing.md" in text and "#no-such-heading" in text
    assert "example.com" not in text and "nowhere.md" not in text and "#a-page" not in text
    assert len(problems) == 2, text
    (tmp_path / "other.md").write_text("# Other\n\n## `[cage]`: CageConfig\n")
    ok = "[a](other.md#cage-cageconfig) [b](other.md#other)"
    assert check_links(ok, page) == []
    assert check_links("[c](other.md#nope)", page)


def test_checkers_read_quickstart_and_makefile():
    assert [" ".join(shell_words(line)) for _, line in command_lines(["make demo   # x", "make test"])] == ["make demo", "make test"]
    targets = makefile_targets("A := 1\n.PHONY: a b\na: b\n\t@echo\nb c:\n$(STAMP): x\n# d: e\n")
    assert targets == {"a", "b", "c"}
    assert github_slug("`[source]`: SourceConfig") == "source-sourceconfig"
    assert github_slug("Measured (2 cores, no GPU)") == "measured-2-cores-no-gpu"
    assert anchors("# A\n## B\n## B\n") == {"a", "b", "b-1"}


def test_checkers_report_a_bad_readme_and_a_stale_reference():
    problems = quickstart_problems(BAD_DOC + "x\n" * 10, max_lines=12)
    text = "\n".join(problems)
    assert "lines (at most 12)" in text and "not make demo and make test" in text
    assert quickstart_problems("# P\n\n## Quickstart\n\n```bash\nmake demo  # a\nmake test\n```\n") == []
    assert quickstart_problems("# P\n\n## Other\n\n## Quickstart\n")
    assert quickstart_problems("# P\n\n```bash\nmake demo\n```\n\n## Quickstart\n\n```bash\nmake demo\nmake test\n```\n")
    assert config_reference_problems("a\nb\n", "a\nb\n") == []
    assert "line 2" in config_reference_problems("a\nb\n", "a\nc\n")[0]


def test_field_help_reads_every_kind_of_documentation():
    import dataclasses

    from workflows.docs import field_help

    @dataclasses.dataclass
    class Example:
        """An example. Exactly one of ``model`` (a built-in name) or ``folder``.

        Attributes:
            n_train, n_test: how many shapes.
            iterations: maximum steps; lr: the learning rate; lr_final: the rate at the end.
            w_*: loss weights. mvc_points: sample size.
            w_rest: the rest term.
        """

        model: str | None = None
        folder: str | None = None
        n_train: int = 24
        n_test: int = 8
        iterations: int = 300
        lr: float = 0.02
        lr_final: float = 0.002
        w_chamfer: float = 1.0
        w_rest: float = 0.1
        mvc_points: int = 64
        tagged: int = dataclasses.field(default=1, metadata={"help": "from the metadata"})
        #: from a comment above,
        #: two lines long
        above: int = 2
        trailing: int = 3  # from a comment after it
        hashed: str = "#not a comment"
        nothing: int = 0

    help_ = field_help(Example)
    assert help_["model"] == "a built-in name"
    assert help_["n_train"] == help_["n_test"] == "how many shapes."
    assert help_["iterations"] == "maximum steps"
    assert help_["lr"] == "the learning rate"
    assert help_["lr_final"] == "the rate at the end."
    assert help_["w_chamfer"] == "loss weights."
    assert help_["w_rest"] == "the rest term."
    assert help_["mvc_points"] == "sample size."
    assert help_["tagged"] == "from the metadata"
    assert help_["above"] == "from a comment above, two lines long"
    assert help_["trailing"] == "from a comment after it"
    assert "hashed" not in help_ and "nothing" not in help_ and "folder" not in help_


# --------------------------------------------------------------------------- figures that agree
def build_speed_rows(readme: str) -> dict[str, dict[str, float]]:
    """The README's build-speed table: ``{row label: {stage or "total": seconds}}``."""
    lines = [l for l in readme.splitlines() if l.startswith("| ") and ("demo," in l or "sofa export," in l)]
    head = ["sample", "paint", "pairs", "train", "evaluate", "total"]
    out = {}
    for line in lines:
        cells = [c.strip().strip("*") for c in line.strip("|").split("|")]
        out[cells[0]] = dict(zip(head, map(float, cells[1:7])))
    return out


def build_figures_disagreeing(readme: str, speed: str, texturing: str) -> list[str]:
    """The build figures given in two places that disagree (issue 55), each named: the README's
    build-speed table is the source; the README's own prose on Ray's train stage, build-speed.md's
    Ray costs and the look's share of a build (README and texturing.md) must follow from it or from
    each other. Texts are compared with their line breaks folded."""
    rows = build_speed_rows(readme)
    readme, speed, texturing = (" ".join(t.split()) for t in (readme, speed, texturing))
    demo, demo_ray = rows["demo, in process, today (median of 3)"], rows["demo, on Ray, today (median of 3)"]
    sofa, sofa_ray = rows["sofa export, in process, today"], rows["sofa export, on Ray, today"]
    bad = []
    train_demo, train_sofa = demo_ray["train"] - demo["train"], sofa_ray["train"] - sofa["train"]
    if f"the train stage takes {train_demo:.1f} s (demo) and {train_sofa:.1f} s (sofa)" not in readme:
        bad.append(f"README: Ray's train stage should read {train_demo:.1f} s (demo) and {train_sofa:.1f} s (sofa)")
    for (ray, proc), name in (((demo_ray, demo), "demo"), ((sofa_ray, sofa), "sofa export")):
        share = round(100 * (ray["total"] / proc["total"] - 1))
        if f"{ray['total']:.1f} against {proc['total']:.1f} s" not in speed or not re.search(rf"\b{share}% (over the in-process build )?on the {name}", speed):
            bad.append(f"build-speed.md: Ray on the {name} should be {share}%, {ray['total']:.1f} against {proc['total']:.1f} s")
    found = re.search(r"the build ([\d.]+) s \(pairs [^)]*\), a look [\d.-]+ s \(median ([\d.]+) s", texturing)
    if found is None:
        return bad + ["texturing.md: the look against the build is not stated"]
    build, look = (float(x) for x in found.groups())
    share = 100 * look / build
    if f"{share:.1f}% of the build" not in texturing:
        bad.append(f"texturing.md: a look should be {share:.1f}% of the build")
    if f"build {build:.1f} s, a look {look:.1f} s, {share:.0f}% of it" not in readme:
        bad.append(f"README: the look should read build {build:.1f} s, a look {look:.1f} s, {share:.0f}% of it")
    return bad


def _build_figure_texts() -> tuple[str, str, str]:
    return README.read_text(), (ROOT / "docs" / "build-speed.md").read_text(), (ROOT / "docs" / "texturing.md").read_text()


def test_the_same_build_figures_say_the_same_everywhere():
    assert build_figures_disagreeing(*_build_figure_texts()) == []


def test_the_figures_check_names_each_figure_that_disagrees():
    """The check reads what it compares: a table row changed, a Ray cost changed, a look's median
    changed each make it name exactly that figure."""
    readme, speed, texturing = _build_figure_texts()
    row = "| demo, on Ray, today (median of 3) | 1.9 | 3.9 | 8.6 | 39.3 |"
    assert row in readme
    bad = build_figures_disagreeing(readme.replace(row, row.replace("39.3", "41.3")), speed, texturing)
    assert len(bad) == 1 and "train stage should read 17.7 s (demo)" in bad[0]
    bad = build_figures_disagreeing(readme, speed.replace("63.4 against 44.3 s", "63.9 against 44.3 s"), texturing)
    assert len(bad) == 1 and bad[0].startswith("build-speed.md: Ray on the demo")
    bad = build_figures_disagreeing(readme, speed, texturing.replace("(median 3.44 s", "(median 3.90 s"))
    assert len(bad) == 2 and {b.split(":")[0] for b in bad} == {"texturing.md", "README"}
