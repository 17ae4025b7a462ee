"""The README and docs/ say what is true: every relative link resolves, every `sianms` command a code
block shows exists with the flags shown, the demo's times have one source, and the README stays a
first page (short, no commit history)."""

from __future__ import annotations

import json
import re
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
PERFORMANCE = ROOT / "docs" / "performance.md"
README_MAX_BYTES = 12_000
README_MAX_HASHES = 2

FENCE = re.compile(r"^\s*(```|~~~)")
LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
INLINE_CODE = re.compile(r"`[^`]*`")
HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$")
HASH_LIKE = re.compile(r"\b(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}\b")
# `sianms CMD`, `python -m sianms_cli CMD`, `torchrun ... -m sianms_cli CMD`
INVOCATION = re.compile(r"(?:^|[\s(])(?:sianms|-m\s+sianms_cli)\s+(.*)$")
FLAG = re.compile(r"(?<![\w-])(--[a-z0-9][a-z0-9-]*)")
TIME_FIGURE = re.compile(r"\b\d+(?:\.\d+)?\s*(?:min|minutes?|s|seconds?|h|hours?)\b", re.IGNORECASE)
DEMO_TIME = re.compile(r"^\| `(sianms demo(?: --quick)?)` \| (\d+(?:\.\d+)?) min \|", re.MULTILINE)


def markdown_files() -> list[Path]:
    """The user's documents: the README, the changelog and every page under docs/."""
    pages = [README, ROOT / "CHANGELOG.md", *sorted((ROOT / "docs").rglob("*.md"))]
    return [page for page in pages if page.exists()]


def shell_examples() -> list[Path]:
    return sorted((ROOT / "examples").glob("*.sh"))


def split_fences(text: str) -> tuple[list[str], list[list[str]]]:
    """(the lines outside fenced code blocks, each fenced block's lines)."""
    prose, blocks, block = [], [], None
    for line in text.splitlines():
        if FENCE.match(line):
            if block is None:
                block = []
            else:
                blocks.append(block)
                block = None
        elif block is None:
            prose.append(line)
        else:
            block.append(line)
    return prose, blocks


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = INLINE_CODE.sub(lambda match: match.group(0).strip("`"), heading)
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", text)  # a link keeps its text
    return re.sub(r"[^\w\- ]", "", text.strip().lower()).replace(" ", "-")


@cache
def anchors(page: Path) -> frozenset[str]:
    """Every anchor GitHub gives the headings of ``page`` (a repeated heading gets -1, -2, ...)."""
    prose, _ = split_fences(page.read_text())
    seen: dict[str, int] = {}
    found = set()
    for line in prose:
        match = HEADING.match(line)
        if match:
            base = slug(match.group(2))
            count = seen.get(base, 0)
            seen[base] = count + 1
            found.add(base if count == 0 else f"{base}-{count}")
    return frozenset(found)


def relative_links(page: Path) -> list[str]:
    prose, _ = split_fences(page.read_text())
    links = []
    for line in prose:
        links += LINK.findall(INLINE_CODE.sub("", line))
    return [link for link in links if not re.match(r"^[a-z][a-z0-9+.-]*:", link)]  # http:, https:, mailto:


def broken_link(page: Path, link: str) -> str | None:
    """Why ``link`` in ``page`` does not resolve, or None."""
    path, _, anchor = link.partition("#")
    target = (page.parent / path).resolve() if path else page
    shown = target.relative_to(ROOT) if target.is_relative_to(ROOT) else target
    if not target.exists():
        return f"{shown} does not exist"
    if anchor and target.suffix == ".md" and anchor not in anchors(target):
        return f"{shown} has no heading '#{anchor}'"
    return None


@pytest.mark.parametrize("page", markdown_files(), ids=lambda page: str(page.relative_to(ROOT)))
def test_every_relative_link_resolves(page):
    problems = [f"{link}: {why}" for link in relative_links(page) if (why := broken_link(page, link))]
    assert problems == []


def test_a_broken_link_and_a_missing_anchor_are_found(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("# Title\n\n## A `code` section: here\n\n[ok](#a-code-section-here) [gone](missing.md)"
                    " [no anchor](#nowhere) `[in code](missing.md)`\n\n```\n[in a block](missing.md)\n```\n")
    broken = [link for link in relative_links(page) if broken_link(page, link)]
    assert broken == ["missing.md", "#nowhere"]


# --- commands and flags ---------------------------------------------------------------------------

@cache
def cli_flags() -> dict[tuple[str, ...], frozenset[str]]:
    """Every command path (("demo",), ("train", "siamese"), ...) and the long options it takes;
    () is the group itself, and a group's path maps to its subcommands' names."""
    from typer.main import get_command

    from sianms_cli.cli import app

    found: dict[tuple[str, ...], frozenset[str]] = {}

    def walk(command, path: tuple[str, ...]) -> None:
        options = {option for param in command.params for option in (*param.opts, *param.secondary_opts)}
        found[path] = frozenset({option for option in options if option.startswith("--")} | {"--help"})
        for name, sub in (getattr(command, "commands", None) or {}).items():
            walk(sub, (*path, name))

    walk(get_command(app), ())
    return found


def logical_lines(lines: list[str]) -> list[str]:
    """Shell lines with their continuations joined: a trailing backslash, or an indented line that
    goes on with more options (a synopsis's ``    [--flag N]``)."""
    joined: list[str] = []
    continues = False
    for line in lines:
        stripped = line.strip()
        goes_on = bool(joined) and line[:1].isspace() and stripped[:1] in ("[", "-")
        if (continues or goes_on) and joined:
            joined[-1] = joined[-1].rstrip("\\ ") + " " + stripped
        else:
            joined.append(line)
        continues = stripped.endswith("\\")
    return joined


def invocations(lines: list[str]) -> list[tuple[tuple[str, ...], list[str], str]]:
    """(the first two words after `sianms`, the long flags, the text) of each `sianms` invocation in
    shell-like ``lines``."""
    found = []
    for line in logical_lines(lines):
        line = re.sub(r"(^|\s)#.*$", "", line)  # a shell comment
        for segment in re.split(r"&&|\|\||;", line):
            match = INVOCATION.search(segment)
            if not match:
                continue
            words = tuple(match.group(1).split()[:2])
            if not re.match(r"[a-z]", words[0] if words else ""):
                continue  # `sianms <command> -h`
            found.append((words, FLAG.findall(match.group(1)), segment.strip()))
    return found


def command_of(words: tuple[str, ...]) -> tuple[str, ...]:
    """The command path ``words`` name: ("demo",), ("train", "siamese"); a shell variable or a
    placeholder in a group's place (``train "$2"``) stays as it is written."""
    command = (re.match(r"[a-z][a-z-]*", words[0]).group(0),)
    is_group = any(len(key) == 2 and key[0] == command[0] for key in cli_flags())
    if is_group and len(words) > 1:
        second = words[1].strip("\"'")
        return (*command, re.match(r"[a-z]*", second).group(0) or second)
    return command


def flag_problems(words: tuple[str, ...], flags: list[str]) -> list[str]:
    """What ``sianms WORDS ... FLAGS`` gets wrong: an unknown command, or flags it does not take. A
    group's subcommand given as a variable must take the flags whichever subcommand it is."""
    commands = cli_flags()
    path = command_of(words)
    if (path[0],) not in commands:
        return [f"no command 'sianms {path[0]}'"]
    subcommands = sorted(key[1] for key in commands if len(key) == 2 and key[0] == path[0])
    if not subcommands or (len(path) == 2 and path[1] in subcommands):
        allowed = commands[path]
    elif len(path) == 2 and path[1][:1] in ("$", "<"):
        allowed = frozenset.intersection(*(commands[(path[0], name)] for name in subcommands))
    else:
        return [f"'sianms {path[0]}' needs one of {subcommands}"]
    return [f"'sianms {' '.join(path)}' has no {flag}" for flag in flags if flag not in allowed]


def documented_invocations() -> list[tuple[str, tuple[str, ...], list[str], str]]:
    found = []
    for page in markdown_files():
        for block in split_fences(page.read_text())[1]:
            found += [(str(page.relative_to(ROOT)), *invocation) for invocation in invocations(block)]
    for script in shell_examples():
        found += [(str(script.relative_to(ROOT)), *invocation)
                  for invocation in invocations(script.read_text().splitlines())]
    return found


def test_the_documents_show_commands():
    shown = {command_of(words) for _, words, _, _ in documented_invocations()}
    assert {("demo",), ("prepare",), ("train", "fpointnet"), ("eval",), ("report",)} <= shown


def test_every_command_in_the_documents_exists_with_the_flags_shown():
    problems = [f"{where}: {text}: {problem}" for where, words, flags, text in documented_invocations()
                for problem in flag_problems(words, flags)]
    assert problems == []


def test_a_flag_the_command_lacks_is_found():
    lines = ["sianms prepare --dataroot D --split val \\", "    --out C --no-such-flag",
             "torchrun --nproc-per-node 2 -m sianms_cli train fpointnet --cache C --num-points 8",
             'sianms train "$2" --cache C --num-points 8', "sianms train --cache C", "sianms frobnicate --x"]
    problems = [problem for words, flags, _ in invocations(lines) for problem in flag_problems(words, flags)]
    assert problems == ["'sianms prepare' has no --no-such-flag", "'sianms train $2' has no --num-points",
                        "'sianms train' needs one of ['fpointnet', 'siamese']", "no command 'sianms frobnicate'"]


# --- the demo's times: one source ------------------------------------------------------------------

def demo_help_texts() -> list[str]:
    from typer.main import get_command

    from sianms_cli.cli import app

    demo = get_command(app).commands["demo"]
    return [demo.help or "", *(param.help or "" for param in demo.params)]


def test_the_demo_help_states_no_time_of_its_own():
    # Its times are measured figures that change with the machine and the code: docs/performance.md
    # holds them, and the help points there instead of keeping a copy that goes stale.
    assert [text for text in demo_help_texts() if TIME_FIGURE.search(text)] == []
    assert any("docs/performance.md" in text for text in demo_help_texts())


def test_the_readme_states_the_demo_times_performance_gives():
    measured = {command: float(minutes) for command, minutes in DEMO_TIME.findall(PERFORMANCE.read_text())}
    assert set(measured) == {"sianms demo", "sianms demo --quick"}
    readme = README.read_text()
    for command, minutes in measured.items():
        stated = re.findall(rf"`{re.escape(command)}` takes (\d+(?:\.\d+)?) min", readme)
        assert stated and {float(figure) for figure in stated} == {minutes}, command


# --- the README is a first page --------------------------------------------------------------------

def test_the_readme_is_short_and_holds_no_commit_history():
    text = README.read_text()
    assert len(text.encode()) <= README_MAX_BYTES
    assert len(HASH_LIKE.findall(text)) <= README_MAX_HASHES


def test_the_readme_opens_with_the_two_commands_ci_runs():
    first_block = split_fences(README.read_text())[1][0]
    commands = [line for line in first_block if line.startswith("python3 -m venv")]
    comments = [line for line in first_block if line.startswith("#")]
    assert len(commands) == 2 and commands[0].endswith("&& sianms demo")
    assert len(comments) == 2 and all(len(comment) <= 120 and not HASH_LIKE.search(comment) for comment in comments)


def test_hash_like_tokens_are_found():
    assert HASH_LIKE.findall("at 23bb38b and a0f44e2, not 2002.08239 nor deadbeef nor 1234567") == ["23bb38b",
                                                                                                    "a0f44e2"]


# --- measurement history ---------------------------------------------------------------------------

MEASUREMENT_KEYS = {"date", "commit", "machine", "command", "figure", "value", "unit"}


@pytest.mark.parametrize("path", sorted((ROOT / "bench" / "results").glob("*.jsonl")), ids=lambda path: path.name)
def test_every_measurement_names_its_date_commit_machine_command_figure_and_unit(path):
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        record, where = json.loads(line), f"{path.name}:{number}"
        assert set(record) >= MEASUREMENT_KEYS, where
        assert re.fullmatch(r"\d{4}-\d{2}-\d{2}", record["date"]), where
        assert record["commit"] is None or re.fullmatch(r"[0-9a-f]{7,40}", record["commit"]), where
        assert isinstance(record["value"], (int, float)) and not isinstance(record["value"], bool), where
        texts = [record[key] for key in ("machine", "command", "figure", "unit")]
        assert all(isinstance(text, str) and text for text in texts), where
