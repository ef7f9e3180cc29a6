"""Sphinx configuration of the torchtasks documentation.

Build with ``make docs`` (``sphinx-build -W --keep-going -b html docs docs/_build/html``): every warning
is an error. Pages are Markdown (MyST); the API reference is generated from the docstrings
(Google style, read by ``sphinx.ext.napoleon``). No network access is needed (no intersphinx).
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

from sphinx.application import Sphinx
from sphinx.util import logging
from sphinx.util.inspect import signature as sphinx_signature
from sphinx.util.inspect import stringify_signature

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(ROOT / "src"))  # build from a checkout even without `pip install -e .`

import torchtasks  # noqa: E402

project = "torchtasks"
author = "torchtasks developers"
copyright = "torchtasks developers, BSD-3-Clause"
release = version = torchtasks.__version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.viewcode",
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
# _generated/ holds files that pages include (the benchmark table); they are not pages themselves
exclude_patterns = ["_build", "_generated", "Thumbs.db", ".DS_Store"]

nitpicky = False
suppress_warnings: list[str] = []

# --- MyST -------------------------------------------------------------------------------------
myst_enable_extensions: list[str] = []
myst_heading_anchors = 3  # [text](page.md#a-heading) links resolve to headings up to level 3

# --- autodoc / napoleon -----------------------------------------------------------------------
autodoc_default_options = {"members": True, "member-order": "bysource"}
autodoc_typehints = "signature"
autodoc_class_signature = "mixed"
autoclass_content = "class"  # the class docstring says what the constructor takes (Args:)
napoleon_google_docstring = True
napoleon_numpy_docstring = False
napoleon_use_rtype = False
# RewardFunction documents its class attributes in a "Class attributes:" section (name: description), the
# named tuples of torchtasks.tasks.transition their fields in a "Fields:" section (an "Attributes:" section
# would describe each field a second time beside autodoc's members)
napoleon_custom_sections = [("Class attributes", "params_style"), ("Fields", "params_style")]

# --- HTML -------------------------------------------------------------------------------------
html_theme = "alabaster"
html_title = f"torchtasks {release}"
html_static_path: list[str] = []
html_theme_options = {
    "description": "Batched, differentiable tasks and rewards for TorchRL",
    "fixed_sidebar": True,
    "page_width": "1100px",
    "sidebar_width": "240px",
}

# --- pages that may not exist yet --------------------------------------------------------------
#: pages listed in the toctree of index.md that other work items write; while a page's file is
#: missing, its toctree entry is dropped (with a message) instead of failing the build
OPTIONAL_PAGES = ("training",)

#: the benchmark table the benchmarks page includes (written by the benchmark run, see benchmarks.md)
BENCHMARK_TABLE = DOCS / "_generated" / "benchmarks_table.md"
BENCHMARK_INCLUDE = "```{include} _generated/benchmarks_table.md\n```"
BENCHMARK_MISSING = (
    "```{note}\nThe benchmark table has not been generated yet: `docs/_generated/benchmarks_table.md` "
    "does not exist. Run the command above to produce it.\n```"
)

#: the line of api.md that the table of reading kinds replaces (generated from ``READING_KINDS``)
READING_KINDS_MARKER = "<!-- the table of reading kinds, generated from READING_KINDS -->"

#: the script that writes the tables of docs/control_suite.md from the presets (see its docstring)
CONTROL_SUITE_TABLES = DOCS / "_scripts" / "control_suite_tables.py"
#: the measured tables docs/control_suite.md includes (written by docs/_scripts/control_suite_exactness.py)
CONTROL_SUITE_MEASURED = (
    DOCS / "_generated" / "control_suite_exactness_table.md",
    DOCS / "_generated" / "control_suite_drift_table.md",
)

logger = logging.getLogger(__name__)


def reading_kinds_table() -> str:
    """A Markdown table of every reading kind: its constructor, its class and the first paragraph of the class's
    docstring (its value, shape and frame). Generated from ``torchtasks.envs.readings.READING_KINDS``, one table
    read by the env, the tests and these docs."""
    import inspect

    from torchtasks.envs.readings import READING_KINDS

    rows = ["| reading | class | value, shape and frame |", "| --- | --- | --- |"]
    for kind, cls in READING_KINDS.items():
        summary = " ".join(inspect.getdoc(cls).split("\n\n", 1)[0].split()).replace("|", "\\|")
        rows.append(
            f"| {{py:func}}`~torchtasks.envs.readings.{kind}` | {{py:class}}`~torchtasks.envs.readings.{cls.__name__}` "
            f"| {summary} |"
        )
    return "\n".join(rows)


def _control_suite_tables() -> ModuleType:
    """``docs/_scripts/control_suite_tables.py`` as a module (the tables of the Control Suite's tasks)."""
    spec = importlib.util.spec_from_file_location("control_suite_tables", CONTROL_SUITE_TABLES)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # where its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def _fill_control_suite(app: Sphinx, source: list[str]) -> None:
    """Replace the two marker lines of docs/control_suite.md with the tables generated from the presets."""
    tables = _control_suite_tables()
    for marker in (tables.OBSERVATION_MARKER, tables.REWARD_MARKER):
        if marker not in source[0]:
            raise RuntimeError(f"docs/control_suite.md must hold the line {marker!r}: a table of the tasks")
    facts = tables.all_task_facts()
    source[0] = source[0].replace(tables.OBSERVATION_MARKER, tables.observation_table(facts))
    source[0] = source[0].replace(tables.REWARD_MARKER, tables.reward_table(facts))
    app.env.note_dependency(str(CONTROL_SUITE_TABLES))
    for table in CONTROL_SUITE_MEASURED:
        app.env.note_dependency(str(table))  # the page is rebuilt when a measured table changes


def _adapt_sources(app: Sphinx, docname: str, source: list[str]) -> None:
    """Leave out toctree entries of missing optional pages and a missing benchmark table; fill in the table of
    reading kinds of the API reference and the tables of the Control Suite's tasks."""
    if docname == root_doc:
        for page in OPTIONAL_PAGES:
            # a dependency on the page (even a missing one) re-reads the index when the page appears
            app.env.note_dependency(str(DOCS / f"{page}.md"))
            if not (DOCS / f"{page}.md").exists():
                logger.info("docs/%s.md does not exist yet: left out of the table of contents", page)
                source[0] = "\n".join(line for line in source[0].split("\n") if line.strip() != page)
    elif docname == "api":
        if READING_KINDS_MARKER not in source[0]:
            raise RuntimeError(f"docs/api.md must hold the line {READING_KINDS_MARKER!r}: the table of reading kinds")
        source[0] = source[0].replace(READING_KINDS_MARKER, reading_kinds_table())
    elif docname == "control_suite":
        _fill_control_suite(app, source)
    elif docname == "benchmarks":
        # a dependency on the table (even a missing one) rebuilds this page when the table changes
        app.env.note_dependency(str(BENCHMARK_TABLE))
        if not BENCHMARK_TABLE.exists():
            logger.info("%s does not exist yet: the benchmarks page shows a note instead", BENCHMARK_TABLE)
            source[0] = source[0].replace(BENCHMARK_INCLUDE, BENCHMARK_MISSING)


def _constructor_signature(
    app: Sphinx,
    what: str,
    name: str,
    obj: object,
    options: object,
    signature: str | None,
    return_annotation: str | None,
) -> tuple[str | None, str | None] | None:
    """Show a class's ``__init__`` signature where a metaclass hides it (TorchRL's ``EnvBase``)."""
    if what != "class" or signature != "(*args, **kwargs)" or "__init__" not in vars(obj):
        return None
    init = sphinx_signature(obj.__init__, bound_method=True)
    return stringify_signature(init, show_return_annotation=False, unqualified_typehints=True), return_annotation


def _namedtuple_fields(app: Sphinx, what: str, name: str, obj: object, options: object, lines: list[str]) -> None:
    """Drop the "Alias for field number N" docstrings of NamedTuple fields (FinalRewardMode)."""
    if what in ("attribute", "property") and len(lines) == 1 and lines[0].startswith("Alias for field number"):
        lines.clear()


def setup(app: Sphinx) -> dict[str, bool]:
    app.connect("source-read", _adapt_sources)
    app.connect("autodoc-process-signature", _constructor_signature)
    app.connect("autodoc-process-docstring", _namedtuple_fields)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
