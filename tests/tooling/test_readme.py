"""The README says what exists: every example, every TorchRL transform, every docs page, where the command lives."""

from __future__ import annotations

import re

import pytest
from torchrl.envs.transforms import Transform

import torchtasks.transforms
from repo_paths import ROOT

README = (ROOT / "README.md").read_text()


def _section(title: str) -> str:
    """The text of the README's ``## title`` section, up to the next ``## `` heading."""
    match = re.search(rf"^## {re.escape(title)}\n(.*?)(?=^## )", README, re.MULTILINE | re.DOTALL)
    assert match is not None, f"README has no '## {title}' section"
    return match.group(1)


EXAMPLES = sorted(path.name for path in (ROOT / "examples").glob("[!_]*.py"))
TRANSFORMS = sorted(
    name
    for name in torchtasks.transforms.__all__
    if isinstance(getattr(torchtasks.transforms, name), type)
    and issubclass(getattr(torchtasks.transforms, name), Transform)
)
DOCS_PAGES = sorted(path.name for path in (ROOT / "docs").glob("*.md") if path.name not in {"index.md", "api.md"})


def test_the_lists_are_not_empty() -> None:
    assert len(EXAMPLES) >= 10 and len(TRANSFORMS) >= 5 and len(DOCS_PAGES) >= 10


@pytest.mark.parametrize("example", EXAMPLES)
def test_every_example_is_listed(example: str) -> None:
    assert f"`{example}`" in _section("Examples"), f"README's Examples section does not list {example}"


@pytest.mark.parametrize("transform", TRANSFORMS)
def test_every_transform_is_named(transform: str) -> None:
    assert f"`{transform}`" in README, f"README does not name the transform {transform}"


@pytest.mark.parametrize("page", DOCS_PAGES)
def test_every_docs_page_is_linked(page: str) -> None:
    assert f"](docs/{page}" in README, f"README does not link docs/{page}"


def test_the_command_is_where_the_readme_says() -> None:
    makefile = (ROOT / "Makefile").read_text()
    venv = re.search(r"^VENV := (\S+)$", makefile, re.MULTILINE).group(1)
    scripts = re.search(r"^\[project\.scripts\]\n(.*?)(?=^\[)", (ROOT / "pyproject.toml").read_text(), re.M | re.S)
    assert scripts is not None and re.search(r"^torchtasks = ", scripts.group(1), re.MULTILINE)
    assert f"`{venv}/bin/torchtasks`" in README


def test_readme_links_point_at_files() -> None:
    for target in re.findall(r"\]\(((?:docs|examples|benchmarks)/[^)#\s]+)", README):
        assert (ROOT / target).exists(), f"README links {target}, which does not exist"
