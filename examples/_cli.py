"""Command-line helpers shared by the example scripts (not a script).

:func:`make_parser` builds an example's ``argparse`` parser: a short ``--help`` (the first paragraph of
the module docstring as plain text, the options with their defaults, 100 columns). :func:`quiet_torchrl`
hides TorchRL's INFO logs (``[torchrl][INFO] Initialized LazyTensorStorage ...``) unless the user asked
for them with ``RL_LOGGING_LEVEL``.
"""

from __future__ import annotations

import argparse
import logging
import os
import re
import warnings

WIDTH = 100  # --help fits this many columns

_ROLE = re.compile(r":[a-z]+(?::[a-z]+)?:`(~?)([^`<]*?)(?:\s*<[^>]*>)?`")
_LITERAL = re.compile(r"``(.+?)``")


def plain(text: str) -> str:
    """Return ``text`` without Sphinx markup: roles become their target (``~`` keeps the last name), literals plain.

    Example:
        >>> plain("Use :func:`~torchtasks.stats.episode_statistics` and ``--quick``.")
        'Use episode_statistics and --quick.'
    """
    text = _ROLE.sub(lambda m: m.group(2).rsplit(".", 1)[-1] if m.group(1) else m.group(2), text)
    return _LITERAL.sub(r"\1", text)


def short_description(doc: str | None) -> str:
    """Return the first paragraph of a module docstring as plain text on one line."""
    first = (doc or "").strip().split("\n\n", 1)[0]
    return " ".join(plain(first).split())


class _Formatter(argparse.HelpFormatter):
    """A help formatter 100 columns wide that appends ``(default: ...)`` to options that do not state it."""

    def __init__(self, prog: str) -> None:
        super().__init__(prog, width=WIDTH, max_help_position=32)

    def _get_help_string(self, action: argparse.Action) -> str:
        text = (action.help or "").strip()
        default = action.default
        if (
            "default" in text
            or default is None
            or default is argparse.SUPPRESS
            or isinstance(action, (argparse._StoreTrueAction, argparse._StoreFalseAction))
        ):
            return text
        shown = " ".join(str(value) for value in default) if isinstance(default, (list, tuple)) else str(default)
        shown = shown.replace("%", "%%")
        return f"{text} (default: {shown})" if text else f"default: {shown}"

    def _format_action(self, action: argparse.Action) -> str:
        if not action.help and action.option_strings and action.default not in (None, argparse.SUPPRESS):
            action.help = "(default: %(default)s)"  # argparse formats only the help of actions that have one
        return super()._format_action(action)


def make_parser(doc: str | None, epilog: str | None = None) -> argparse.ArgumentParser:
    """Return a parser whose ``--help`` is the docstring's first paragraph and the options with their defaults."""
    return argparse.ArgumentParser(
        usage="%(prog)s [-h] [options]",
        description=short_description(doc),
        epilog=epilog or "Details: the module docstring of this script. TorchRL's INFO logs: RL_LOGGING_LEVEL=INFO.",
        formatter_class=_Formatter,
    )


def quiet_torchrl() -> None:
    """Show only TorchRL's warnings and errors, unless the environment variable ``RL_LOGGING_LEVEL`` says otherwise.

    Also silences the one warning the examples trigger on purpose: ``VecNormV2`` on a batched env is "experimental"
    (``reduce_batch_dims=True`` is what a batch needs), and TorchRL repeats it wherever it re-checks the transform (the
    collector, the frozen copies).
    """
    import torchrl  # noqa: F401  (torchrl sets its logger's level when imported: set ours after)

    if "RL_LOGGING_LEVEL" not in os.environ:
        logging.getLogger("torchrl").setLevel(logging.WARNING)
    warnings.filterwarnings("ignore", message="Support of VecNormV2 for containers", category=UserWarning)
