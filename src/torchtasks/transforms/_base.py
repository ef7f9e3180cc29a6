"""The base classes of the torchtasks transforms that derive facts from the env they sit in.

:class:`EnvDerivedTransform` caches facts of its env and forgets them when that env changes, and finds the
transforms of its env also from TorchRL's clones; :class:`ResetWritingTransform` writes the run's values before
the base env resets.
"""

from __future__ import annotations

import weakref
from typing import Any

from tensordict import TensorDict, TensorDictBase
from torchrl.envs.transforms import Transform

from torchtasks._torchrl import container_env, flat_transforms

__all__ = ["EnvDerivedTransform", "ResetWritingTransform"]


class EnvDerivedTransform(Transform):
    """A transform that caches facts derived from the env it sits in, and forgets them when that env changes.

    Subclasses implement :meth:`_forget_setup` (drop the cached facts); moving the transform into another
    container, re-parenting it or cloning it (TorchRL clones the transforms before a transform to build
    that transform's ``parent`` env) calls it, so the next spec building or step derives them anew.
    :meth:`home_transforms` finds the transforms of the env the transform works in, also from such a clone.
    """

    def _forget_setup(self) -> None:
        raise NotImplementedError

    def set_container(self, container: Transform | Any) -> None:
        super().set_container(container)
        self._forget_setup()

    def reset_parent(self) -> None:
        super().reset_parent()
        self._forget_setup()

    def clone(self) -> EnvDerivedTransform:
        copy = super().clone()
        copy._forget_setup()
        # a clone in a later transform's parent env (TorchRL's partial view of the env) sees none of the transforms
        # after it; home_transforms answers for the transform it was cloned from
        copy.__dict__["_original"] = weakref.ref(self)
        return copy

    def __getstate__(self) -> dict[str, Any]:
        state = super().__getstate__()
        state.pop("_original", None)  # a weak reference: not picklable, and meaningless in a copy
        return state

    def home_transforms(self) -> tuple[list[Transform], int] | None:
        """The leaf transforms of the env this transform works in and its index among them; ``None`` outside an env.

        For a clone in TorchRL's ``parent`` view built for a later transform (the same base env, the transforms
        before that later one cloned), the answer of the transform it was cloned from, whose env also holds the
        transforms the view leaves out.
        """
        env = container_env(self)
        transform = getattr(env, "transform", None)
        if transform is None:
            return None
        flat = flat_transforms(transform)
        position = next(i for i, t in enumerate(flat) if t is self)
        original = self.__dict__.get("_original")
        source = None if original is None else original()
        if source is not None and source is not self:
            home = source.home_transforms()
            source_env = container_env(source)
            if (
                home is not None
                and home[1] == position
                and len(home[0]) > len(flat)
                and getattr(source_env, "base_env", None) is getattr(env, "base_env", False)
            ):
                return home
        return flat, position


class ResetWritingTransform(EnvDerivedTransform):
    """An env-derived transform whose ``_reset`` writes buffers that the env or earlier transforms read at reset.

    TorchRL resets the base env, then runs the transforms' ``_reset`` in order, so a buffer written there
    comes too late for the base env's reset (a start state) and for an earlier transform's (the
    TaskTransform copying a desired state into the episode's memory). This class also runs ``_reset``
    (on a scratch TensorDict) in ``_reset_env_preprocess``, which TorchRL calls before the base env
    resets: the first episode, and the first one of a resumed run, see the values of the run's state.
    """

    def _reset_env_preprocess(self, tensordict: TensorDictBase | None) -> TensorDictBase | None:
        tensordict = super()._reset_env_preprocess(tensordict)
        self._write_run_values(tensordict)
        return tensordict

    def _write_run_values(self, tensordict: TensorDictBase | None = None) -> None:
        """Write the values of the run's state into their buffers now (as ``_reset`` does), e.g. after a load."""
        env = container_env(self)
        if env is not None:
            self._reset(tensordict, TensorDict(batch_size=env.batch_size, device=env.device))
