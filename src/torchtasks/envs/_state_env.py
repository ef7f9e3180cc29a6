"""The base of the batched torch envs (pendulum, point mass): the observation is the state, nothing ends by itself."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from torchtasks._checks import check_int, check_non_negative_int


class StateEnv(EnvBase):
    """A batch of simulated systems whose observation is their raw state, stepped as one tensor.

    Subclasses give the initial-state distribution (:meth:`_sample_state`) and the dynamics
    (:meth:`_next_state`); this class holds the specs (``observation [*B, state_size]``, an action
    in ``±action_bound`` of ``[*B, action_size]``, ``done``/``terminated`` flags), the env's own
    random generator, partial resets (only the entries of ``"_reset"`` get a new state) and a step
    that pays no reward and ends no episode: the task on the env does both.

    Checkpoints: ``env.state_dict()`` holds the reset generator (its seed and state, under
    ``"_extra_state"``) and the batch size; after ``load_state_dict`` (into an env of the same batch
    size, else a ``ValueError``) the env draws the initial states that the saved one would have drawn
    next, bit for bit. The env keeps nothing else between steps: a running episode's state is its
    observation, which the caller (a collector's carried data) holds, so the extra state marks the
    running episodes as saved (``"running_episodes": {}``) and
    :func:`torchtasks.checkpoint.load_collector_state` continues them. TorchRL's
    ``Collector.state_dict()`` and ``TransformedEnv.state_dict()`` save the transforms of a
    ``TransformedEnv``, not its base env: put a :class:`~torchtasks.transforms.BaseEnvState` in it.
    """

    batch_locked = True

    def __init__(
        self,
        batch_size: Sequence[int] | torch.Size,
        *,
        state_size: int,
        action_size: int,
        action_bound: float,
        dtype: torch.dtype,
        device: torch.device | str | None,
        seed: int | None,
    ) -> None:
        owner = type(self).__name__
        if isinstance(batch_size, (str, bytes)) or not isinstance(batch_size, Sequence):
            raise TypeError(
                f"{owner}: batch_size must be a sequence of non-negative ints (e.g. [4]), got {batch_size!r} "
                f"of type {type(batch_size).__name__}"
            )
        batch_size = [check_non_negative_int(n, f"{owner}: batch_size[{i}]") for i, n in enumerate(batch_size)]
        super().__init__(batch_size=torch.Size(batch_size), device=device)
        self.dtype_ = dtype
        self.rng = torch.Generator(device=self.device or "cpu")
        self._set_seed(seed)
        batch = self.batch_size
        self.observation_spec = Composite(
            observation=Unbounded(shape=(*batch, state_size), dtype=dtype, device=self.device), shape=batch
        )
        self.action_spec = Bounded(
            low=-action_bound, high=action_bound, shape=(*batch, action_size), dtype=dtype, device=self.device
        )
        self.reward_spec = Unbounded(shape=(*batch, 1), dtype=dtype, device=self.device)
        self.done_spec = Composite(
            done=Categorical(2, shape=(*batch, 1), dtype=torch.bool, device=self.device),
            terminated=Categorical(2, shape=(*batch, 1), dtype=torch.bool, device=self.device),
            shape=batch,
        )

    def _sample_state(self) -> torch.Tensor:
        """Initial states of the whole batch, ``[*B, state_size]``, drawn with ``self.rng``."""
        raise NotImplementedError

    def _next_state(self, state: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """The states after one step from ``state`` with ``action`` (clipping the action is the subclass's)."""
        raise NotImplementedError

    def _flags(self, reference: torch.Tensor) -> torch.Tensor:
        return torch.zeros((*self.batch_size, 1), dtype=torch.bool, device=reference.device)

    def _reset(self, tensordict: TensorDictBase | None, **kwargs: object) -> TensorDictBase:
        state = self._sample_state()
        if tensordict is not None and "_reset" in tensordict.keys() and "observation" in tensordict.keys():
            reset = tensordict.get("_reset").reshape(*self.batch_size, 1)
            state = torch.where(reset, state, tensordict.get("observation"))
        flags = self._flags(state)
        return TensorDict(
            {"observation": state, "done": flags, "terminated": flags.clone()},
            batch_size=self.batch_size,
            device=self.device,
        )

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        state = tensordict.get("observation")
        next_state = self._next_state(state, tensordict.get("action"))
        flags = self._flags(state)
        return TensorDict(
            {
                "observation": next_state,
                "reward": state.new_zeros((*self.batch_size, 1)),
                "done": flags,
                "terminated": flags.clone(),
            },
            batch_size=self.batch_size,
            device=self.device,
        )

    def _set_seed(self, seed: int | None) -> None:
        if seed is None:
            seed = int(torch.empty((), dtype=torch.int64).random_().item())
        seed = check_int(seed, f"{type(self).__name__}: seed")
        self.rng.manual_seed(seed)

    # ------------------------------------------------------------------ checkpoints
    def get_extra_state(self) -> dict[str, Any]:
        """The reset generator, the batch size and the (empty) running-episode state.

        ``{"seed": int, "generator_state": uint8 tensor, "batch_size": list[int], "running_episodes": {}}``.
        """
        return {
            "seed": self.rng.initial_seed(),
            "generator_state": self.rng.get_state(),
            "batch_size": list(self.batch_size),
            "running_episodes": {},
        }

    def set_extra_state(self, state: Any) -> None:
        """Restore the reset generator saved by :meth:`get_extra_state` (refused for another batch size)."""
        owner = type(self).__name__
        saved = state.get("generator_state") if isinstance(state, Mapping) else None
        if not isinstance(saved, torch.Tensor) or saved.dtype != torch.uint8:
            raise ValueError(
                f"{owner}.load_state_dict: the extra state must be a dict with a uint8 tensor "
                f"'generator_state' (as {owner}.state_dict() writes it), got {state!r}"
            )
        batch_size = state.get("batch_size")  # absent from checkpoints written before it was saved
        if batch_size is not None and list(batch_size) != list(self.batch_size):
            raise ValueError(
                f"{owner}.load_state_dict: the checkpoint is of an env of batch_size {list(batch_size)}, this env "
                f"has batch_size {list(self.batch_size)}: its generator would draw other initial states"
            )
        self.rng.set_state(saved.cpu())
