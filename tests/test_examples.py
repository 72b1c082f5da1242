"""Every example of README.md and docs/*.md runs as pasted, in a fresh folder.

Per page, its ``python`` blocks run in order in one namespace (as a reader pastes them one after the other into one
session), and its ``bash`` blocks line by line: a line that calls ``surfnorm`` runs the command in this process
(exit status 0 expected), any other line (``mkdir``, ``cp``) runs in bash. ``pycon`` blocks are doctests
(``make doctest``). A block that cannot run here says so on the line before its fence,
``<!-- not run: REASON -->`` (an optional extra, a cluster, a device, minutes of benchmarking); those are counted
and listed, never skipped silently. The counts are printed at the end of the run (tests/conftest.py).
"""

from __future__ import annotations

import re
import shlex
import subprocess
import warnings
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md"] + sorted((ROOT / "docs").glob("*.md"))
NOT_RUN = re.compile(r"<!--\s*not run:\s*(.+?)\s*-->")
FENCE = re.compile(r"^```(\w*)\s*$")

COUNTS: dict[str, int] = {"python": 0, "surfnorm": 0, "shell": 0, "not run": 0}
NOT_RUN_LIST: list[str] = []


@dataclass
class Block:
    page: Path
    line: int  # 1-based line of the opening fence
    lang: str
    code: str
    not_run: str | None


def blocks(page: Path) -> list[Block]:
    """The fenced code blocks of a page, with the ``not run`` reason of the line before each."""
    lines = page.read_text(encoding="utf-8").splitlines()
    out, i = [], 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if m is None:
            i += 1
            continue
        start, lang = i, m.group(1)
        j = i + 1
        while j < len(lines) and lines[j].strip() != "```":
            j += 1
        if j == len(lines):
            raise AssertionError(f"{page.name}:{start + 1}: a code fence that is never closed")
        before = lines[start - 1] if start > 0 else ""
        reason = NOT_RUN.search(before)
        out.append(Block(page, start + 1, lang, "\n".join(lines[start + 1 : j]), reason.group(1) if reason else None))
        i = j + 1
    return out


def shell_lines(code: str) -> list[str]:
    """Shell commands of a block: continuation lines joined, comments and blank lines dropped."""
    joined = re.sub(r"\\\n\s*", " ", code)
    out = []
    for line in joined.splitlines():
        words = shlex.split(line, comments=True)
        if words:
            out.append(line)
    return out


def run_shell_line(line: str, where: str, folder: Path):
    from typer.testing import CliRunner

    from surfnorm.cli import app

    words = shlex.split(line, comments=True)
    if words[0] == "surfnorm":
        result = CliRunner().invoke(app, words[1:], env={"COLUMNS": "120"})
        assert result.exit_code == 0, f"{where}: `{line.strip()}` exited {result.exit_code}: {result.output}"
    else:
        done = subprocess.run(["bash", "-ec", line], cwd=folder, capture_output=True, text=True, timeout=60)
        assert done.returncode == 0, f"{where}: `{line.strip()}` failed: {done.stderr}"


@pytest.mark.slow
@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_example_of_the_page_runs(page, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    namespace: dict = {"__name__": "__example__"}
    for b in blocks(page):
        where = f"{page.relative_to(ROOT).as_posix()}:{b.line}"
        if b.lang not in ("python", "bash"):
            continue
        if b.not_run is not None:
            COUNTS["not run"] += 1
            NOT_RUN_LIST.append(f"{where} ({b.lang}): {b.not_run}")
            continue
        if b.lang == "python":
            COUNTS["python"] += 1
            with warnings.catch_warnings():
                warnings.simplefilter("error")  # an example that warns is a broken example
                exec(compile(b.code, where, "exec"), namespace)  # noqa: S102 - the documentation's own examples
        else:
            for line in shell_lines(b.code):
                COUNTS["surfnorm" if shlex.split(line, comments=True)[0] == "surfnorm" else "shell"] += 1
                run_shell_line(line, where, tmp_path)


def test_blocks_without_a_language_are_text():
    """A bare fence would render its content literally: every block says what it is."""
    bare = [f"{b.page.name}:{b.line}" for page in PAGES for b in blocks(page) if not b.lang]
    assert not bare, f"code blocks without a language: {bare}"


def summary_lines() -> list[str]:
    """The counts, for the end of the test run (tests/conftest.py prints them)."""
    lines = [
        f"documentation examples: {COUNTS['python']} python blocks, {COUNTS['surfnorm']} surfnorm command lines "
        f"(and {COUNTS['shell']} other shell lines) run; {COUNTS['not run']} blocks marked not run"
    ]
    lines += [f"  not run: {x}" for x in NOT_RUN_LIST]
    return lines
