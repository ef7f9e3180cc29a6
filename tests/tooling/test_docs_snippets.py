"""Run every ```python block of README.md and docs/*.md as its own test.

Each block is executed in a fresh namespace, so every block must be self-contained (its own
imports). A block that cannot run on its own by design (e.g. it uses a placeholder env) opts out
with a marker comment on its first line::

    # not-runnable: <reason>
    # doctest: +SKIP

Test ids are ``<file>:<line of the opening fence>``; a failing block's traceback points at the
lines of the Markdown file. A block fails if it emits any warning (a reader who runs it would see it):
every warning is recorded, except the TorchRL notices ``import torchtasks`` silences for every user.
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import pytest
import torch

from repo_paths import ROOT
from torchtasks._warnings import quiet_torchrl_notices

DOC_FILES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

PYTHON_LANGUAGES = {"python", "py", "python3"}
# MyST directives that take the language as their argument, e.g. ```{code-block} python
CODE_DIRECTIVES = {"{code-block}", "{code}", "{sourcecode}"}
OPENING_FENCE = re.compile(r"^(?P<indent> {0,3})(?P<fence>`{3,}|~{3,})\s*(?P<info>.*?)\s*$")
SKIP_MARKER = re.compile(r"^#\s*(?:doctest:\s*\+SKIP\b|not-runnable:\s*(?P<reason>\S.*))", re.IGNORECASE)


@dataclass(frozen=True)
class Snippet:
    """One fenced python block of a Markdown file."""

    path: Path
    line: int  # 1-based line of the opening fence
    source: str

    @property
    def id(self) -> str:
        return f"{self.path.relative_to(ROOT).as_posix()}:{self.line}"

    @property
    def skip_reason(self) -> str | None:
        """The reason given by a marker comment on the block's first line, else None."""
        first_line = self.source.lstrip("\n").split("\n", 1)[0].strip()
        match = SKIP_MARKER.match(first_line)
        if match is None:
            return None
        return f"{self.id}: {match.group('reason') or 'doctest: +SKIP'}"


def _language(info: str) -> str:
    words = info.split()
    if not words:
        return ""
    if words[0] in CODE_DIRECTIVES:
        return words[1].lower() if len(words) > 1 else ""
    return words[0].lower()


def _is_closing(line: str, fence: str) -> bool:
    stripped = line.rstrip()
    indent = len(stripped) - len(stripped.lstrip(" "))
    body = stripped.lstrip(" ")
    return indent <= 3 and len(body) >= len(fence) and set(body) == {fence[0]}


def _dedent(line: str, width: int) -> str:
    """Remove up to ``width`` leading spaces (CommonMark: the opening fence's indentation)."""
    spaces = len(line) - len(line.lstrip(" "))
    return line[min(spaces, width) :]


def iter_python_blocks(path: Path) -> Iterator[Snippet]:
    """Yield the fenced python blocks of a CommonMark/MyST file (an unclosed fence runs to the end)."""
    lines = path.read_text(encoding="utf-8").splitlines()
    index = 0
    while index < len(lines):
        opening = OPENING_FENCE.match(lines[index])
        if opening is None or (opening["fence"][0] == "`" and "`" in opening["info"]):
            index += 1
            continue
        fence, indent, start = opening["fence"], len(opening["indent"]), index
        body: list[str] = []
        index += 1
        while index < len(lines) and not _is_closing(lines[index], fence):
            body.append(_dedent(lines[index], indent))
            index += 1
        index += 1  # past the closing fence
        if _language(opening["info"]) in PYTHON_LANGUAGES:
            yield Snippet(path, start + 1, "\n".join(body) + "\n")


SNIPPETS = [snippet for path in DOC_FILES if path.is_file() for snippet in iter_python_blocks(path)]


def test_snippets_are_found() -> None:
    """Guard against a parser regression silently turning the snippet tests into no tests."""
    found = {snippet.path.name for snippet in SNIPPETS}
    expected = {path.name for path in DOC_FILES if path.is_file() and "```python" in path.read_text(encoding="utf-8")}
    assert found == expected


@pytest.fixture
def restore_torch_state() -> Iterator[None]:
    """Undo global torch settings a snippet may change, so snippets cannot affect other tests."""
    dtype, grad = torch.get_default_dtype(), torch.is_grad_enabled()
    rng = torch.get_rng_state()
    yield
    torch.set_default_dtype(dtype)
    torch.set_grad_enabled(grad)
    torch.set_rng_state(rng)


@contextmanager
def record_warnings() -> Iterator[list[warnings.WarningMessage]]:
    """Record every warning of the block as a user would see it after ``import torchtasks``.

    pytest resets the filters around each test, and ``simplefilter("always")`` (which also shows a warning
    already shown elsewhere in this process) goes in front of them all, torchtasks' included: so the
    package's filters are installed again after it, in front, as they are in a user's process.
    """
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        quiet_torchrl_notices()
        yield caught


def test_recording_keeps_only_torchtasks_filters() -> None:
    """The snippets' recorder drops what ``import torchtasks`` silences, and records everything else."""
    silenced = "The env passed to Collector is missing transforms required by the policy (InitTracker). From ..."
    shown = "The env passed to Collector is missing transforms required by the policy (InitTracker, TensorDictPrimer). "
    with record_warnings() as caught:
        for message in (silenced, shown):
            warnings.warn_explicit(message, FutureWarning, "_single.py", 1, module="torchrl.collectors._single")
        for _ in range(2):  # recorded twice: "always"
            warnings.warn("about the user's code", DeprecationWarning, stacklevel=1)
    assert [str(warning.message) for warning in caught] == [shown] + ["about the user's code"] * 2


QUICK_SNIPPET = next(snippet for snippet in SNIPPETS if snippet.path.name == "README.md")  # in `make test-quick`


@pytest.mark.parametrize(
    "snippet",
    [pytest.param(snippet, marks=pytest.mark.quick) if snippet is QUICK_SNIPPET else snippet for snippet in SNIPPETS],
    ids=[snippet.id for snippet in SNIPPETS],
)
def test_snippet_runs(snippet: Snippet, restore_torch_state: None) -> None:
    reason = snippet.skip_reason
    if reason is not None:
        pytest.skip(reason)
    # pad with blank lines so that tracebacks show the line numbers of the Markdown file
    code = compile("\n" * snippet.line + snippet.source, str(snippet.path), "exec")
    namespace = {"__name__": "__docs_snippet__", "__file__": str(snippet.path)}
    with record_warnings() as caught:
        exec(code, namespace)
    shown = [f"{item.filename}:{item.lineno}: {item.category.__name__}: {item.message}" for item in caught]
    assert not shown, f"{snippet.id} emits {len(shown)} warning(s), a reader would see:\n" + "\n".join(shown)
