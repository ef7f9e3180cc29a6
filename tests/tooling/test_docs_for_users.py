"""The docs speak to users: no internal history of the project in README.md, benchmarks/README.md or docs/.

A reader with a fresh clone cannot look up "issue 31", "the issue's target" or a commit of this repository; every
figure they read must stand on its own (its date, command and floor beside it). External references stay: a link to
another project's file at one of its commits (a URL), an upstream issue written as ``pytorch/rl#4341``.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from repo_paths import ROOT

TEXT_SUFFIXES = {".md", ".py", ".json", ".txt", ".rst"}
DOCS = sorted(
    path
    for path in (ROOT / "docs").rglob("*")
    if path.is_file() and path.suffix in TEXT_SUFFIXES and "_build" not in path.relative_to(ROOT).parts
)
FILES = [ROOT / "README.md", ROOT / "benchmarks" / "README.md", *DOCS]

#: what only the people who built torchtasks can resolve
INTERNAL = {
    "an issue number": re.compile(r"(?<![a-z])issues?[\s_-]*#?\d+", re.IGNORECASE),
    "a reference to 'the issue'": re.compile(r"\bthe issue(?:'s|s')?\b", re.IGNORECASE),
    # a hex word of 7-40 characters with a digit and a letter (a short or full commit hash), or any hex word
    # named as a commit or checkout
    "a commit hash": re.compile(
        r"\b(?=[0-9a-f]*[0-9])(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}\b"
        r"|\b(?:commit|checkout of|revision)\s+`?[0-9a-f]{7,40}\b",
        re.IGNORECASE,
    ),
}
URL = re.compile(r"https?://[^\s)>\]]+")


def internal_history(text: str) -> list[tuple[int, str, str]]:
    """``(line number, kind, match)`` of every piece of internal history in ``text`` (URLs are not read)."""
    found = []
    for number, line in enumerate(text.splitlines(), start=1):
        line = URL.sub("", line)
        for kind, pattern in INTERNAL.items():
            found.extend((number, kind, match.group(0)) for match in pattern.finditer(line))
    return found


def test_the_scan_finds_each_kind_and_spares_external_references() -> None:
    text = (
        "Measured before issue 31.\n"
        "The issue's target is not met; rerun on the final code of the issue.\n"
        "The forward term changed in commit a3a9191; a checkout of 2369056 was slower.\n"
        "See pytorch/rl#4341 and [OmniSafe](https://github.com/PKU-Alignment/omnisafe/blob/15603dd/README.md).\n"
        "Raw numbers in docs/_generated/pipeline_costs_issue23.json; 1,001,472 frames, seed 12345, 1e-9.\n"
    )
    kinds = [(number, kind) for number, kind, _ in internal_history(text)]
    assert kinds == [
        (1, "an issue number"),
        (2, "a reference to 'the issue'"),
        (2, "a reference to 'the issue'"),
        (3, "a commit hash"),
        (3, "a commit hash"),
        (5, "an issue number"),
    ], kinds


def test_the_files_are_found() -> None:
    assert len(DOCS) >= 20 and all(path.exists() for path in FILES), FILES


@pytest.mark.parametrize("path", FILES, ids=lambda path: path.relative_to(ROOT).as_posix())
def test_no_internal_history(path: Path) -> None:
    """No issue number, "the issue('s)" or commit hash in the file, nor an issue number in its name."""
    relative = path.relative_to(ROOT).as_posix()
    found = [f"{relative}:{number}: {kind}: {match!r}" for number, kind, match in internal_history(path.read_text())]
    found += [f"{relative}: {kind} in the file name" for _, kind, _ in internal_history(path.name)]
    assert not found, "internal history in the user docs (say what was measured, when, with which command):\n" + (
        "\n".join(found)
    )
