"""Optional dependencies: the extras of ``pip install 'torchtasks[EXTRA]'`` and the error that names them.

The core (``torchtasks``, ``.spaces``, ``.rewards``, ``.tasks``, ``.predefined``, ``.transforms``,
``.envs``, the ``torchtasks`` command and its demo) needs only torch, tensordict, torchrl, numpy and
tqdm. A feature that needs an extra imports it on use and, when it is missing, raises the
:class:`ModuleNotFoundError` of :func:`missing_extra` naming the extra and the ``pip`` command.
"""

from __future__ import annotations

import importlib.util

__all__ = ["EXTRAS", "has_extra", "install_hint", "missing_extra"]

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


def install_hint(extra: str) -> str:
    """The ``pip`` command that installs ``extra``.

    Example:
        >>> install_hint("mujoco")
        "pip install 'torchtasks[mujoco]'"
    """
    return f"pip install 'torchtasks[{extra}]'"


def missing_extra(extra: str, feature: str, error: BaseException | None = None) -> ModuleNotFoundError:
    """Return the error for ``feature`` used without ``extra`` (``error``: the import error behind it).

    Example:
        >>> print(missing_extra("mujoco", "torchtasks check"))
        torchtasks check needs the 'mujoco' extra: pip install 'torchtasks[mujoco]'
    """
    message = f"{feature} needs the '{extra}' extra: {install_hint(extra)}"
    if error is not None:
        message += f" ({type(error).__name__}: {error})"
    return ModuleNotFoundError(message, name=getattr(error, "name", None))
