"""MuJoCo's warnings as Python warnings: no ``MUJOCO_LOG.TXT`` in the user's directory, no bare console lines.

MuJoCo reports a warning (a compiler deprecation, an unstable simulation) by printing it and
appending it to ``MUJOCO_LOG.TXT`` in the current directory, unless a user warning handler is set.
:func:`route_mujoco_warnings` sets one that issues a :class:`MujocoWarning` instead, so Python's
``warnings`` filters decide what is shown (and tests can assert on it). It keeps a handler the user set
first. :func:`quiet_model_loading` hides the deprecation MuJoCo 4 reports for Gymnasium's own v5
model files (``settotalmass`` in ``half_cheetah.xml``): the project pins those files and their
compiled model must stay bit-identical, so the notice is ours to act on, not the user's.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from contextlib import contextmanager

import mujoco

__all__ = ["MujocoWarning", "quiet_model_loading", "route_mujoco_warnings"]

#: the deprecations of Gymnasium's v5 model files that MuJoCo 4 reports while compiling them
_KNOWN_MODEL_NOTICES = (r"MuJoCo: compiler attribute 'settotalmass' is deprecated",)


class MujocoWarning(RuntimeWarning):
    """A warning reported by MuJoCo (its message, prefixed with ``MuJoCo:``)."""


def _warn(message: str) -> None:
    warnings.warn(f"MuJoCo: {message}", MujocoWarning, stacklevel=2)


def route_mujoco_warnings() -> None:
    """Send MuJoCo's warnings to Python's ``warnings`` (as :class:`MujocoWarning`) unless a handler is set.

    Example:
        >>> import mujoco
        >>> from torchtasks.envs._mujoco_log import route_mujoco_warnings
        >>> route_mujoco_warnings()
        >>> mujoco.get_mju_user_warning() is not None
        True
    """
    if mujoco.get_mju_user_warning() is None:
        mujoco.set_mju_user_warning(_warn)


@contextmanager
def quiet_model_loading() -> Iterator[None]:
    """Hide the known deprecation notices of Gymnasium's v5 model files while a model is compiled.

    Example:
        >>> import gymnasium, warnings
        >>> from torchtasks.envs._mujoco_log import quiet_model_loading, route_mujoco_warnings
        >>> route_mujoco_warnings()
        >>> with warnings.catch_warnings(record=True) as caught:
        ...     warnings.simplefilter("always")
        ...     with quiet_model_loading():
        ...         env = gymnasium.make("HalfCheetah-v5")
        >>> [str(w.message) for w in caught if "settotalmass" in str(w.message)]
        []
        >>> env.close()
    """
    with warnings.catch_warnings():
        for notice in _KNOWN_MODEL_NOTICES:
            warnings.filterwarnings("ignore", message=notice, category=MujocoWarning)
        yield
