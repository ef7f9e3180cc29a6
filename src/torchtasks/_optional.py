"""Optional dependencies: the extras of pyproject.toml, and errors naming the command that installs them.

The core (``torchtasks``, ``.spaces``, ``.rewards``, ``.tasks``, ``.predefined``, ``.transforms``,
``.envs``, the ``torchtasks`` command and its demo) needs only torch, tensordict, torchrl, numpy and
tqdm. A feature that needs an extra imports it on use and, when it is missing, raises the
:class:`ModuleNotFoundError` of :func:`missing_extra` naming the extra and the ``pip`` command.
"""

from __future__ import annotations

import importlib.util
import shlex
from pathlib import Path

__all__ = ["EXTRAS", "checkout_root", "has_extra", "install_hint", "missing_extra"]

#: each extra of pyproject.toml and the modules it provides (those the code imports)
EXTRAS: dict[str, tuple[str, ...]] = {
    "mujoco": ("mujoco", "gymnasium"),
    "plot": ("matplotlib",),
    "ray": ("ray",),
}


def _installed(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        return False


def has_extra(extra: str) -> bool:
    """Whether every module of ``extra`` can be imported (it is only looked up, not imported).

    Example:
        >>> has_extra("no-such-extra")
        Traceback (most recent call last):
        ...
        KeyError: 'no-such-extra'
    """
    return all(_installed(module) for module in EXTRAS[extra])


def checkout_root() -> Path | None:
    """The repository this package runs from (an editable install of a checkout), or None for an installed wheel.

    Example:
        >>> root = checkout_root()
        >>> root is None or (root / "pyproject.toml").is_file()
        True
    """
    root = Path(__file__).resolve().parents[2]
    pyproject = root / "pyproject.toml"
    if (root / "src" / "torchtasks").is_dir() and pyproject.is_file():
        try:
            if 'name = "torchtasks"' in pyproject.read_text(encoding="utf-8"):
                return root
        except OSError:
            return None
    return None


def install_hint(extra: str) -> str:
    """The ``pip`` command that installs ``extra`` where this package came from.

    From a checkout (an editable install, as ``make setup`` makes) it installs the checkout's extra with its pinned
    versions (``constraints.txt``), written relative to the current directory when that is the checkout; from an
    installed wheel it names the package's extra.

    Example:
        >>> hint = install_hint("mujoco")
        >>> hint.startswith("pip install") and "[mujoco]'" in hint
        True
    """
    root = checkout_root()
    if root is None:
        return f"pip install 'torchtasks[{extra}]'"
    try:
        here = Path.cwd().resolve() == root
    except OSError:
        here = False
    constraints = "constraints.txt" if here else str(root / "constraints.txt")
    target = "." if here else str(root)
    pins = f"-c {shlex.quote(constraints)} " if (root / "constraints.txt").is_file() else ""
    return f"pip install {pins}-e {shlex.quote(target + f'[{extra}]')}"


def missing_extra(extra: str, feature: str, error: BaseException | None = None) -> ModuleNotFoundError:
    """Return the error for ``feature`` used without ``extra`` (``error``: the import error behind it).

    Example:
        >>> print(missing_extra("mujoco", "torchtasks check"))  # doctest: +ELLIPSIS
        torchtasks check needs the 'mujoco' extra: pip install ...[mujoco]'
    """
    message = f"{feature} needs the '{extra}' extra: {install_hint(extra)}"
    if error is not None:
        message += f" ({type(error).__name__}: {error})"
    return ModuleNotFoundError(message, name=getattr(error, "name", None))
