"""Command-line helpers shared by the example scripts (not a script).

:func:`make_parser` builds an example's ``argparse`` parser: a short ``--help`` (the first paragraph of
the module docstring as plain text, then one line or two per option: a description and its default,
100 columns). Every default is written by :func:`default_text` (``(default: 0 1 2)``, ``(default:
2,097,152)``), options with a ``default=`` get it appended by the formatter, and the metavars are short
(``N`` for integers, ``X`` for floats, ``PATH`` for paths unless the option says ``DIR``).
:func:`config_arguments` adds a flag per field of a config dataclass, described by a table of field
descriptions. :func:`frame_bar` is the progress bar of every example: it counts env frames.
:func:`quiet_torchrl` hides TorchRL's INFO logs (``[torchrl][INFO] Initialized LazyTensorStorage ...``)
unless the user asked for them with ``RL_LOGGING_LEVEL``.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import os
import warnings
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from torchtasks.cli import QUICK_FOLDER, SuggestingParser, make_output_folder
from torchtasks.cli import output_folder as resolve_output

if TYPE_CHECKING:
    from tqdm import tqdm

WIDTH = 100  # --help fits this many columns
EPILOG = "Details: the module docstring of this script. TorchRL's INFO logs: RL_LOGGING_LEVEL=INFO."


def short_description(doc: str | None) -> str:
    """Return the first paragraph of a module docstring as plain text on one line (the ``torchtasks`` command's
    :func:`~torchtasks.cli.plain_text`: no Sphinx roles or literals).

    Example:
        >>> short_description("Use :func:`~torchtasks.stats.episode_statistics` and ``--quick``.\\n\\nDetails.")
        'Use episode_statistics and --quick.'
    """
    from torchtasks.cli import plain_text

    return plain_text((doc or "").strip().split("\n\n", 1)[0])


def shown(value: Any) -> str:
    """A default value as ``--help`` writes it: no Python reprs, thousands separators from 10,000 on.

    Example:
        >>> shown([0, 1, 2]), shown(("her", "plain")), shown(2_097_152), shown(8192), shown(1e-3), shown(10.0)
        ('0 1 2', 'her plain', '2,097,152', '8192', '0.001', '10')
    """
    if isinstance(value, str):
        return value
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, bool):
        return "on" if value else "off"
    if isinstance(value, Iterable):
        return " ".join(shown(item) for item in value)
    if isinstance(value, float) and value.is_integer() and abs(value) < 1e15:
        value = int(value)
    if isinstance(value, int):
        return f"{value:,}" if abs(value) >= 10_000 else str(value)
    return repr(value) if isinstance(value, float) else str(value)


def add_output_argument(parser: argparse.ArgumentParser, default: Path, what: str) -> None:
    """Add ``--output DIR`` (``what`` the run writes there), whose default is ``default``, ``default/quick`` for a
    ``--quick`` run: a smoke run never overwrites a full run's results. :func:`output_folder` resolves it.

    Example:
        >>> import tempfile
        >>> parser = make_parser("An example.")
        >>> _ = parser.add_argument("--quick", action="store_true")
        >>> add_output_argument(parser, Path("runs/demo"), "directory for the JSON")
        >>> with tempfile.TemporaryDirectory() as root:
        ...     args = parser.parse_args(["--quick", "--output", f"{root}/x"])
        ...     output_folder(parser, args, Path("runs/demo")).is_dir()
        True
    """
    note = f"{default / QUICK_FOLDER} with --quick"
    parser.add_argument(
        "--output", type=Path, default=None, metavar="DIR", help=f"{what} {default_text(str(default), note)}"
    )


def output_folder(parser: argparse.ArgumentParser, args: argparse.Namespace, default: Path) -> Path:
    """The ``--output`` folder of ``args`` parsed by ``parser``, created before the run: the one given, else
    ``default`` (``default/quick`` with --quick), the ``torchtasks`` command's rule
    (:func:`torchtasks.cli.output_folder`). A folder that cannot be created or written is refused on one line
    with the system's reason (``parser.error``: exit status 2), before anything runs."""
    folder = resolve_output(args.output, default, args.quick)
    problem = make_output_folder(folder)
    if problem is not None:
        parser.error(problem)
    return folder


def default_text(value: Any, note: str = "") -> str:
    """``(default: VALUE)``, or ``(default: VALUE; note)``: how every option of every example states its default.

    ``%`` is doubled (argparse %-formats help strings). A string value is shown as it is, so a default
    that is not a value can be said in words: ``default_text("start a local one")``.

    Example:
        >>> default_text([0, 1, 2]), default_text(64_000, "2,400 with --quick")
        ('(default: 0 1 2)', '(default: 64,000; 2,400 with --quick)')
    """
    text = shown(value) + (f"; {note}" if note else "")
    return f"(default: {text})".replace("%", "%%")


class _Formatter(argparse.HelpFormatter):
    """100 columns; appends :func:`default_text` to options whose help does not state a default; short metavars."""

    def __init__(self, prog: str) -> None:
        super().__init__(prog, width=WIDTH, max_help_position=32)

    def _get_help_string(self, action: argparse.Action) -> str:
        text = (action.help or "").strip()
        default = action.default
        if (
            "(default: " in text
            or default is None
            or default is argparse.SUPPRESS
            or isinstance(action, (argparse._StoreTrueAction, argparse._StoreFalseAction))
        ):
            return text
        return f"{text} {default_text(default)}".strip()

    def _get_default_metavar_for_optional(self, action: argparse.Action) -> str:
        short = {int: "N", float: "X", Path: "PATH"}
        return short.get(action.type, action.dest.upper())  # type: ignore[call-overload]

    def _format_action(self, action: argparse.Action) -> str:
        if not action.help and action.option_strings and action.default not in (None, argparse.SUPPRESS):
            action.help = " "  # argparse formats only the help of actions that have one
        return super()._format_action(action)


def make_parser(doc: str | None) -> argparse.ArgumentParser:
    """Return a parser whose ``--help`` is the docstring's first paragraph and the options with their defaults.

    It is the ``torchtasks`` command's :class:`~torchtasks.cli.SuggestingParser`: a misspelt option gets ``did you
    mean '--quick'?``, a misspelt choice the choice meant.
    """
    return SuggestingParser(
        usage="%(prog)s [-h] [options]",
        description=short_description(doc),
        epilog=EPILOG,
        formatter_class=_Formatter,
    )


def config_arguments(
    parser: argparse.ArgumentParser, defaults: Any, descriptions: Mapping[str, str], names: Iterable[str] | None = None
) -> None:
    """Add ``--field-name`` for the fields ``names`` (default: all) of the config dataclass instance ``defaults``.

    Each flag takes the field's type (``N`` or ``X``), is described by ``descriptions[name]`` (one table
    beside the dataclass) and shows the field's value in ``defaults`` as its default. The parsed value is
    None unless given: the caller replaces only the fields the user set (``--quick`` has its own config).
    """
    values = dataclasses.asdict(defaults)
    for name in values if names is None else names:
        value = values[name]
        parser.add_argument(
            f"--{name.replace('_', '-')}",
            type=type(value),
            help=f"{descriptions[name]} {default_text(value)}",
        )


def time_unit(seconds: float) -> tuple[float, str]:
    """The unit of a wall-time axis up to ``seconds``: ``(seconds per unit, name)``, seconds below 2 minutes.

    Example:
        >>> time_unit(13.0), time_unit(600.0), time_unit(3 * 3600.0)
        ((1.0, 's'), (60.0, 'min'), (3600.0, 'h'))
    """
    if seconds < 120.0:
        return 1.0, "s"
    return (60.0, "min") if seconds < 2 * 3600.0 else (3600.0, "h")


def duration(seconds: float) -> str:
    """``seconds`` in the unit of :func:`time_unit` (a 13 s run in seconds, a 40 min run in minutes).

    Example:
        >>> duration(3.61), duration(600.0), duration(3 * 3600.0)
        ('3.6 s', '10.0 min', '3.00 h')
    """
    per_unit, unit = time_unit(seconds)
    return f"{seconds / per_unit:.{2 if unit == 'h' else 1}f} {unit}"


def frame_bar(description: str, total: int | None, until: str = "") -> tqdm:
    """The progress bar of every example: it counts env frames (``frame``, scaled: ``12.3kframe/s``).

    ``total``: the frames the run will collect (its frame budget). A run without one, ended by a success
    target or a time limit, passes None and says what ends it in ``until`` (``"80% success or 10 min"``):
    the bar then counts the frames without a total. Drawn on a terminal only, as the ``torchtasks`` command's
    bars: a log file gets the run's summary lines, not carriage-return updates.
    """
    from tqdm import tqdm

    if total is None and until:
        description = f"{description} (until {until})"
    return tqdm(total=total, desc=description, unit="frame", unit_scale=True, disable=None)


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
