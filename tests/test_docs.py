"""The user's guide stays a guide: README.md at most 250 lines, no history, every command it
names exists, every file it links exists; every table of docs/performance.md is dated and
gives its command."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
PERFORMANCE = ROOT / "docs" / "performance.md"
HISTORY = re.compile(r"\b(issue \d+|previous (run|session|version)|earlier session|revision "
                     r"[0-9a-f]{7}|as before|no longer|used to)\b", re.IGNORECASE)


def test_readme_is_short_and_has_no_history():
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 250, f"README.md has {len(lines)} lines"
    hits = [f"{n}: {line}" for n, line in enumerate(lines, 1) if HISTORY.search(line)]
    assert not hits, "history in README.md:\n" + "\n".join(hits)


def test_readme_links_and_commands_exist():
    from rtdefocus.cli import build_parser

    text = README.read_text(encoding="utf-8")
    for target in re.findall(r"\]\(([^)#]+)\)", text):
        if "://" not in target:
            assert (ROOT / target).exists(), f"README links to a missing file: {target}"
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    named = set(re.findall(r"^\s*rtdefocus ([a-z]+)", text, re.MULTILINE))
    named |= set(re.findall(r"`rtdefocus ([a-z]+)", text))
    assert named, "the README shows no command"
    assert named <= set(sub.choices), f"unknown subcommands: {sorted(named - set(sub.choices))}"


def test_performance_tables_are_dated_with_command_and_machine():
    text = PERFORMANCE.read_text(encoding="utf-8")
    assert not HISTORY.search(text), HISTORY.search(text)
    # The text between one table and the next carries the date and the command in backticks,
    # or says the table comes from the same run (or day and machine) as the one before.
    heads, head, in_table = [], [], False
    for line in text.splitlines():
        if line.startswith("|"):
            if not in_table:
                heads.append("\n".join(head))
                head = []
            in_table = True
        else:
            in_table = False
            head.append(line)
    assert len(heads) >= 8
    for h in heads:
        same = "same run" in h or "same day" in h
        assert re.search(r"20\d\d-\d\d-\d\d", h) or same, f"table without a date after: {h[-200:]!r}"
        assert "`" in h or same, f"table without its command after: {h[-200:]!r}"
