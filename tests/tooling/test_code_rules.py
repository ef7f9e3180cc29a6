"""Two rules of the code base, checked over the whole package.

- Every public class (in the ``__all__`` of a module or package of torchtasks) has a docstring of at most 50 lines:
  what it does, its arguments and an example; the rationale goes in the docs pages.
- No module reads another module's private names: neither ``from torchtasks.x import _name`` (a private module,
  ``torchtasks._checks``, is the package's shared room and may be imported from) nor ``Name._attr`` on a name
  imported from another module, unless a class of the reading module derives from it (a subclass uses its base's
  protected hooks). The owner gives a public accessor, or the fact moves where it belongs.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import pkgutil
from pathlib import Path

import torchtasks
from repo_paths import ROOT

MAX_CLASS_DOCSTRING_LINES = 50
SOURCE = ROOT / "src"


def public_classes() -> dict[str, type]:
    """``{qualified name: class}`` of every class exported by a public module of torchtasks (its ``__all__``)."""
    classes: dict[str, type] = {}
    for info in pkgutil.walk_packages(torchtasks.__path__, "torchtasks."):
        if any(part.startswith("_") for part in info.name.split(".")):
            continue
        module = importlib.import_module(info.name)
        for name in getattr(module, "__all__", ()):
            value = getattr(module, name)
            if inspect.isclass(value) and value.__module__.startswith("torchtasks."):
                classes[f"{value.__module__}.{value.__qualname__}"] = value
    return classes


def test_every_public_class_has_a_docstring_of_at_most_50_lines() -> None:
    classes = public_classes()
    assert len(classes) >= 80, sorted(classes)
    lengths = {
        name: len(inspect.cleandoc(cls.__dict__.get("__doc__") or "").splitlines()) for name, cls in classes.items()
    }
    missing = sorted(name for name, lines in lengths.items() if lines == 0)
    long = sorted(f"{name}: {lines} lines" for name, lines in lengths.items() if lines > MAX_CLASS_DOCSTRING_LINES)
    assert not missing, f"public classes without a docstring: {missing}"
    assert not long, (
        f"class docstrings over {MAX_CLASS_DOCSTRING_LINES} lines (move the rationale to a docs page): {long}"
    )


def _module_name(path: Path) -> str:
    parts = path.relative_to(SOURCE).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def private_reads(source: str, module: str) -> list[tuple[int, str]]:
    """``(line, what)`` of every read of another torchtasks module's private name in ``source`` (of ``module``)."""
    tree = ast.parse(source)
    imported: dict[str, str] = {}  # local name -> the torchtasks module it comes from
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("torchtasks"):
            private_module = any(part.startswith("_") for part in node.module.split("."))
            for alias in node.names:
                if _is_private(alias.name) and not private_module:
                    found.append((node.lineno, f"from {node.module} import {alias.name}"))
                imported[alias.asname or alias.name] = node.module
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith("torchtasks"):
                    imported[alias.asname or alias.name.split(".")[0]] = alias.name
    bases = {
        base.id
        for node in ast.walk(tree)
        if isinstance(node, ast.ClassDef)
        for base in node.bases
        if isinstance(base, ast.Name)
    }
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Attribute)
            and isinstance(node.value, ast.Name)
            and node.value.id in imported
            and imported[node.value.id] != module
            and node.value.id not in bases
            and _is_private(node.attr)
        ):
            found.append((node.lineno, f"{node.value.id}.{node.attr} ({imported[node.value.id]})"))
    return sorted(found)


def _is_private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def test_private_reads_finds_both_kinds_and_spares_the_allowed() -> None:
    source = (
        "from torchtasks._checks import check_int\n"  # a private module's public name: the package's shared room
        "from torchtasks.envs.locomotion import _preset_env\n"  # a public module's private name
        "from torchtasks.tasks.transition import Transition\n"
        "from torchtasks.tasks.protocol import Task\n"
        "fields = Transition._fields\n"  # a private attribute of another module's class
        "class Leaf(Task):\n"
        "    def f(self):\n"
        "        return Task._has_failed(self)\n"  # a subclass calls its base's protected hook
    )
    assert private_reads(source, "torchtasks.tasks.leaf") == [
        (2, "from torchtasks.envs.locomotion import _preset_env"),
        (5, "Transition._fields (torchtasks.tasks.transition)"),
    ]


def test_no_module_reads_another_modules_private_names() -> None:
    paths = sorted((SOURCE / "torchtasks").rglob("*.py"))
    assert len(paths) >= 50
    found = [
        f"{path.relative_to(ROOT)}:{line}: {what}"
        for path in paths
        for line, what in private_reads(path.read_text(encoding="utf-8"), _module_name(path))
    ]
    assert not found, "modules reading another module's private names:\n" + "\n".join(found)
