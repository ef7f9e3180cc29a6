"""Loads that pass the checks construction ran: :class:`CheckedLoad`, a mixin for modules with run state.

``nn.Module.load_state_dict`` copies saved tensors into buffers of the same shape and nothing more: a
checkpoint of another configuration (targets listed in another order, a wider goal space, a cost weight
a constructor refuses) loads without a word. A module that mixes in :class:`CheckedLoad` runs its
``_check_loaded()`` once the module and its children are loaded; if the check raises, the state from
before the load is put back and the error propagates, so a refused load changes nothing.

A non-strict load (``load_state_dict(..., strict=False)``) of a partial state dict loads the entries it holds and
leaves the others as they are: TorchRL's ``EnvCreator`` (which ``ParallelEnv`` wraps a lambda in) loads every new
env with the state dict of a first env from which it dropped the tensors. The checks see the module's own entries in
place of the missing ones, so an entry that is there passes the checks it would pass in a whole checkpoint; a strict
load of a partial state dict is refused before anything is written.
"""

from __future__ import annotations

import copy
import sys
from collections.abc import Mapping
from typing import Any

from torch import nn

_BEFORE = "_state_before_load"  # the module's state_dict() as it was when a load began
_RESTORING = "_restoring_state"  # set while a refused load puts the earlier state back


class CheckedLoad(nn.Module):
    """A module whose loaded state passes :meth:`_check_loaded`; a refused load leaves the module as it was.

    Mix it in before the torch base class (``class Curriculum(CheckedLoad, Transform)``) and implement
    :meth:`_check_loaded`; :meth:`_check_saved` refuses a checkpoint from its entries before anything is written,
    and :meth:`_prepare_load` adapts the module to them (e.g. takes the saved shapes) in every load. The state is
    copied at the start of every load, before either changes anything (a load is rare: a resume, not a step).
    """

    def _check_saved(self, state_dict: Any, prefix: str) -> None:
        """Raise ``ValueError`` if the entries under ``prefix`` are not a checkpoint of this configuration."""

    def _prepare_load(self, state_dict: Any, prefix: str) -> None:
        """Adapt the module to the entries about to be loaded (also when a refused load puts the old state back)."""

    def _check_loaded(self) -> None:
        """Raise ``ValueError`` if the loaded state is one the module's constructor or set-up would refuse."""
        raise NotImplementedError

    def _load_from_state_dict(self, state_dict: Any, prefix: str, *args: Any, **kwargs: Any) -> None:
        if not self.__dict__.get(_RESTORING, False):
            before = self.state_dict()
            self._check_saved(state_dict if _strict_load() else _completed(state_dict, prefix, before), prefix)
            self.__dict__[_BEFORE] = copy.deepcopy(before)
            if _after_load not in self._load_state_dict_post_hooks.values():
                self.register_load_state_dict_post_hook(_after_load)
        self._prepare_load(state_dict, prefix)
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)


def _after_load(module: nn.Module, incompatible_keys: Any) -> None:
    """The post-load hook of a :class:`CheckedLoad` module: check, and put the earlier state back on a refusal."""
    before = module.__dict__.pop(_BEFORE, None)
    if before is None or module.__dict__.get(_RESTORING, False):
        return
    try:
        module._check_loaded()
    except Exception:
        module.__dict__[_RESTORING] = True
        try:
            module.load_state_dict(before)
        finally:
            module.__dict__[_RESTORING] = False
        raise


def _strict_load() -> bool:
    """Whether the running ``load_state_dict`` is strict (its ``strict`` argument; ``True`` outside one).

    Torch passes ``strict=True`` to every module's ``_load_from_state_dict`` whatever the caller asked, and applies
    ``strict`` only to the key lists at the end of the load: the argument is read from the innermost
    ``nn.Module.load_state_dict`` call on the stack (a load is rare: a resume or a new env, never a step).
    """
    code = nn.Module.load_state_dict.__code__
    frame = sys._getframe(1)
    while frame is not None:
        if frame.f_code is code:
            return bool(frame.f_locals.get("strict", True))
        frame = frame.f_back
    return True


def _completed(state_dict: Mapping[str, Any], prefix: str, own: Mapping[str, Any]) -> dict[str, Any]:
    """``state_dict`` with the module's own entries (``own``, its ``state_dict()``) in place of the missing ones."""
    completed = {prefix + key: value for key, value in own.items()}
    completed.update(state_dict)
    return completed
