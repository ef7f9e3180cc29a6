"""Loads that pass the checks construction ran: :class:`CheckedLoad`, a mixin for modules with run state.

``nn.Module.load_state_dict`` copies saved tensors into buffers of the same shape and nothing more: a
checkpoint of another configuration (targets listed in another order, a wider goal space, a cost weight
a constructor refuses) loads without a word. A module that mixes in :class:`CheckedLoad` runs its
``_check_loaded()`` once the module and its children are loaded; if the check raises, the state from
before the load is put back and the error propagates, so a refused load changes nothing.

One ``load_state_dict`` call loads many modules, one after the other (TorchRL's ``env.load_state_dict`` and
``collector.load_state_dict`` load the transforms in order). The modules with run state loaded in one call form a
*load*: when one of them refuses its entries, the ones loaded before it in the same call are put back too
(:func:`join_load`, :func:`refuse_load`), so a checkpoint refused by a later transform leaves the earlier ones as
they were. A module that refuses and is not one of them (a TorchRL transform's own check) is outside this guarantee.

A non-strict load (``load_state_dict(..., strict=False)``) of a partial state dict loads the entries it holds and
leaves the others as they are: TorchRL's ``EnvCreator`` (which ``ParallelEnv`` wraps a lambda in) loads every new
env with the state dict of a first env from which it dropped the tensors. The checks see the module's own entries in
place of the missing ones, so an entry that is there passes the checks it would pass in a whole checkpoint; a strict
load of a partial state dict is refused before anything is written.
"""

from __future__ import annotations

import copy
import sys
from collections.abc import Callable, Mapping
from types import FrameType
from typing import Any

from torch import nn

_BEFORE = "_state_before_load"  # the module's state_dict() as it was when a load began
#: the running load: the outermost ``nn.Module.load_state_dict`` frame (held, so its identity is not reused) and how
#: to put back each module loaded so far in it, in load order
_LOAD: list[tuple[FrameType, list[Callable[[], None]]]] = []
#: not empty while earlier states are being put back (their loads are not new loads to count): the modules whose own
#: state is being loaded back (not checked again), or None for a whole load's put-back
_ROLLING_BACK: list[object] = []


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
        if not _restoring(self):
            before = self.state_dict()
            try:
                self._check_saved(state_dict if _strict_load() else _completed(state_dict, prefix, before), prefix)
            except Exception:
                refuse_load()
                raise
            self.__dict__[_BEFORE] = copy.deepcopy(before)
            if _after_load not in self._load_state_dict_post_hooks.values():
                self.register_load_state_dict_post_hook(_after_load)
        self._prepare_load(state_dict, prefix)
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)


def _after_load(module: nn.Module, incompatible_keys: Any) -> None:
    """The post-load hook of a :class:`CheckedLoad` module: check, and put the earlier state back on a refusal."""
    before = module.__dict__.pop(_BEFORE, None)
    if before is None or _restoring(module):
        return
    try:
        module._check_loaded()
    except Exception:
        _restore(module, before)
        refuse_load()
        raise
    join_load(module, lambda: _restore(module, before))


def _restore(module: nn.Module, before: Mapping[str, Any]) -> None:
    """Load ``before`` (the module's earlier ``state_dict()``) back, without the checks of a new load."""
    _ROLLING_BACK.append(module)
    try:
        module.load_state_dict(before)
    finally:
        _ROLLING_BACK.pop()


def _restoring(module: nn.Module) -> bool:
    """Whether ``module``'s earlier state is being loaded back (:func:`_restore`)."""
    return any(held is module for held in _ROLLING_BACK)


def join_load(module: nn.Module, restore: Callable[[], None]) -> None:
    """Count ``module``, just loaded, in the running ``load_state_dict`` call: ``restore()`` puts its earlier state
    back if a module loaded after it in the same call refuses (:func:`refuse_load`). Outside a load, or when
    ``module`` is the one the call loads (nothing follows it), nothing."""
    outermost = _outermost_load()
    if outermost is None or _ROLLING_BACK:
        return
    root = outermost.f_locals.get("self")
    if root is module or not isinstance(root, nn.Module):
        _LOAD.clear()
        return
    if not _LOAD or _LOAD[0][0] is not outermost:  # the first module of a new call
        _LOAD[:] = [(outermost, [])]
        if _end_load not in root._load_state_dict_post_hooks.values():
            root.register_load_state_dict_post_hook(_end_load)  # runs after every module of the call has loaded
    _LOAD[0][1].append(restore)


def refuse_load() -> None:
    """A module refused its entries: put back every module loaded before it in the running ``load_state_dict`` call,
    last first, so that the refused call changes nothing (the refusing module restores itself)."""
    outermost = _outermost_load()
    if not _LOAD or outermost is None or _LOAD[0][0] is not outermost or _ROLLING_BACK:
        return
    restorers = _LOAD[0][1]
    _LOAD.clear()
    _ROLLING_BACK.append(None)
    try:
        for restore in reversed(restorers):
            restore()
    finally:
        _ROLLING_BACK.pop()


def _end_load(module: nn.Module, incompatible_keys: Any) -> None:
    """The post-load hook of a module whose ``load_state_dict`` call loaded modules with run state: the call has
    loaded everything, its list is done."""
    if _LOAD and _LOAD[0][0].f_locals.get("self") is module:
        _LOAD.clear()


def _outermost_load() -> FrameType | None:
    """The frame of the outermost ``nn.Module.load_state_dict`` call on the stack (None outside a load)."""
    code = nn.Module.load_state_dict.__code__
    frame, outermost = sys._getframe(1), None
    while frame is not None:
        if frame.f_code is code:
            outermost = frame
        frame = frame.f_back
    return outermost


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
