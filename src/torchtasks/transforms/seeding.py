"""Seed the generators of torchtasks transforms from ``env.set_seed``: :class:`SeededTransform` and its hook.

TorchRL's ``TransformedEnv.set_seed(seed)`` seeds the base env only: its transforms get nothing. A
transform that owns a generator (today :class:`~torchtasks.transforms.GoalCommand`) subclasses
:class:`SeededTransform` and implements ``set_seed(seed: int)``; then ``env.set_seed(seed)`` on the
``TransformedEnv`` it sits in does what TorchRL does (seeds the base env, returns TorchRL's next seed)
and then seeds each such transform with a seed derived from ``seed`` and the transform's identity in
that env (:func:`derived_seed`): its index among the seeded transforms of the env (those of nested
``TransformedEnv``\\ s below counted first) and its :meth:`~SeededTransform.seed_identity` (class name,
plus the goal key for a GoalCommand). So two GoalCommands of one env draw different streams, a
transform's stream is not the base env's (which TorchRL seeds with ``seed`` itself), and workers draw
different streams because ``SerialEnv``/``ParallelEnv``/``Collector``/``MultiSyncCollector`` pass each
worker env its own seed (``seed``, then TorchRL's next seed, ...). The same seed gives the same run.

``env.set_seed(None)`` seeds the base env as TorchRL does and leaves the transforms' generators as
they are. :func:`seed_transforms` does the transform part alone, e.g. for an env whose base env is
seeded elsewhere.

What a seed changes, for every seeded transform as for TorchRL's base envs: the draws from then on. The
running episodes keep what they were reset with (goals and their timers, physics), because the data a
collector carries from one step to the next was made with it: a ``Collector`` resets its env when it is
built and keeps that reset's output, which no transform can change, so a ``set_seed`` that changed the
running episodes would make the next frame's root entries disagree with what the env simulates. A run
therefore repeats from its first frame when it is seeded before its first reset (``env.set_seed(s)``, then
build the ``Collector``) or reset after the seed (``collector.set_seed(s); collector.reset()``; TorchRL's
multi-process collectors reset after seeding by themselves). ``collector.set_seed(s)`` alone seeds what
comes after the episodes its construction started.

Mechanism, and why: when a :class:`SeededTransform` learns the ``TransformedEnv`` it sits in, it
installs on that env *instance* (``env.__dict__["set_seed"]``) a small picklable callable,
:class:`SeedHook`, which Python finds before the class's ``set_seed``. Every TorchRL path calls
``env.set_seed`` on the env instance: ``SerialEnv`` on each worker env, a ``ParallelEnv`` worker process
on the env its factory built (the hook is installed there, in that process, when the factory builds
the env), ``Collector.set_seed`` on its env, ``MultiSyncCollector`` through each worker's collector, and
an outer ``TransformedEnv`` on its base env; each hook seeds the transforms of its own env once. The
transform learns its env when TorchRL sets its container, and, for a transform inside a ``Compose``
(whose container is the Compose, placed into the env later), when ``TransformedEnv`` puts the
transform chain in eval mode right after setting its container (which it does whenever a transform
is set, appended or inserted); both are idempotent. The hook holds its env (so that
``make_env().set_seed(s)`` works on a temporary too): env and hook form a reference cycle, which
Python's garbage collector frees (close envs explicitly, as TorchRL recommends, rather than rely on
when that happens). Copies and pickles of the env hold a copy of the hook bound to the copy.

Alternatives rejected: patching ``TransformedEnv.set_seed`` on the class changes TorchRL for every
user of the process on import; a ``TransformedEnv`` subclass would not reach envs built by user
factories or TorchRL itself (auto-unwrapping, parent views); seeding lazily from the base env is
impossible because envs do not expose the seed they got (``GymEnv`` does not).

Example:
    >>> import torch
    >>> from torchrl.envs import Compose, SerialEnv, StepCounter, TransformedEnv
    >>> from torchtasks.transforms import GoalCommand
    >>> from torchtasks.envs import PointMassEnv
    >>> from torchtasks.spaces import Box
    >>> def make_env():
    ...     return TransformedEnv(PointMassEnv(batch_size=[2]), Compose(
    ...         StepCounter(20), GoalCommand(Box([-1.0, -1.0], [1.0, 1.0]))))
    >>> env = SerialEnv(2, make_env)
    >>> next_seed = env.set_seed(123)  # seeds both workers' point masses AND their GoalCommands
    >>> goals = env.reset()["goal"]
    >>> bool((goals[0] != goals[1]).all())  # each worker its own stream
    True
    >>> other = SerialEnv(2, make_env)
    >>> _ = other.set_seed(123)
    >>> torch.equal(other.reset()["goal"], goals)  # the same seed: the same goals
    True
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from typing import Any

import torch
from torchrl.envs import EnvBase, TransformedEnv
from torchrl.envs.transforms import Transform

from torchtasks._checks import check_int
from torchtasks._torchrl import container_env, flat_transforms

__all__ = ["SeedHook", "SeededTransform", "derived_seed", "seed_transforms"]


def derived_seed(seed: int, index: int, identity: str) -> int:
    """The seed of the ``index``-th seeded transform of an env seeded with ``seed``: 63 bits of a BLAKE2b hash.

    Stable across processes, platforms and Python versions (not Python's randomised ``hash``); it
    differs from ``seed`` itself (the base env's seed) and between indices and identities.

    Example:
        >>> from torchtasks.transforms import derived_seed
        >>> derived_seed(123, 0, "GoalCommand('goal')") == derived_seed(123, 0, "GoalCommand('goal')")
        True
        >>> derived_seed(123, 0, "GoalCommand('goal')") != derived_seed(123, 1, "GoalCommand('goal')")
        True
    """
    seed = check_int(seed, "derived_seed: seed")
    index = check_int(index, "derived_seed: index")
    if not isinstance(identity, str):
        raise TypeError(f"derived_seed: identity must be a str, got {identity!r} of type {type(identity).__name__}")
    text = f"torchtasks.seeding|{seed}|{index}|{identity}".encode()
    return int.from_bytes(hashlib.blake2b(text, digest_size=8).digest(), "little") >> 1


class SeededTransform(Transform):
    """A TorchRL transform that owns a random generator seeded by ``env.set_seed`` (see this module's docstring).

    Subclasses implement :meth:`set_seed`, may refine :meth:`seed_identity`, and call ``super()`` in
    ``set_container`` and ``train`` if they override them. Placing the transform into a
    ``TransformedEnv`` installs a :class:`SeedHook` on that env, so that ``env.set_seed(seed)`` (and every
    TorchRL path that calls it) also seeds the transform.

    Example:
        >>> import torch
        >>> from torchrl.envs import StepCounter, TransformedEnv
        >>> from torchtasks.envs import PendulumEnv
        >>> from torchtasks.transforms import SeededTransform
        >>> class Noise(SeededTransform):
        ...     def __init__(self):
        ...         super().__init__()
        ...         self.generator = torch.Generator()
        ...     def set_seed(self, seed: int) -> None:
        ...         self.generator.manual_seed(seed)
        >>> noise = Noise()
        >>> env = TransformedEnv(PendulumEnv(batch_size=[2]), noise)
        >>> _ = env.set_seed(0)
        >>> first = torch.rand(2, generator=noise.generator)
        >>> _ = env.set_seed(0)
        >>> torch.equal(first, torch.rand(2, generator=noise.generator))
        True
    """

    def set_seed(self, seed: int) -> None:
        """Seed the transform's own generator with ``seed`` (an int)."""
        raise NotImplementedError(f"{type(self).__name__} must implement set_seed(seed: int)")

    def seed_identity(self) -> str:
        """What tells this transform apart from other seeded transforms of an env (mixed into its seed).

        The class name by default; transforms that may appear several times refine it (a GoalCommand
        adds its goal key).
        """
        return type(self).__name__

    def set_container(self, container: Transform | EnvBase) -> None:
        super().set_container(container)
        _install_seed_hook(container_env(self))

    def train(self, mode: bool = True) -> SeededTransform:
        # TransformedEnv puts its transform chain in eval mode right after setting its container: the one
        # moment a transform deep in a Compose (whose container is the Compose) can see its env
        super().train(mode)
        _install_seed_hook(container_env(self))
        return self


class GeneratorTransform(SeededTransform):
    """A :class:`SeededTransform` whose randomness is one ``torch.Generator``, ``self.generator``, saved in checkpoints.

    ``self.generator`` is the transform's own generator, or ``None`` for torch's global one (until ``set_seed``).
    The transform's extra state (``state_dict()["_extra_state"]``) is the configuration a checkpoint must match,
    which a subclass gives in :meth:`_saved_configuration`, followed by ``"generator_state"`` (the generator's
    state, ``None`` without an own generator); loading it restores the generator. A subclass that refuses
    checkpoints of another configuration (``CheckedLoad._check_saved``) ends its check with
    :meth:`_check_saved_generator`.

    Example:
        >>> import torch
        >>> from torchtasks.transforms.seeding import GeneratorTransform
        >>> class Jitter(GeneratorTransform):
        ...     def __init__(self, scale: float):
        ...         super().__init__()
        ...         self.scale, self.generator = scale, None
        ...     def set_seed(self, seed: int) -> None:
        ...         self.generator = torch.Generator().manual_seed(seed)
        ...     def _saved_configuration(self) -> dict:
        ...         return {"scale": self.scale}
        >>> jitter = Jitter(0.5)
        >>> jitter.set_seed(3)
        >>> state = jitter.state_dict()
        >>> state["_extra_state"]["scale"], state["_extra_state"]["generator_state"].dtype
        (0.5, torch.uint8)
        >>> first = torch.rand(2, generator=jitter.generator)
        >>> jitter.load_state_dict(state)  # the generator as it was when saved
        <All keys matched successfully>
        >>> torch.equal(torch.rand(2, generator=jitter.generator), first)
        True
    """

    generator: torch.Generator | None

    def _saved_configuration(self) -> dict[str, Any]:
        """The configuration a checkpoint must match (the extra state's entries before ``"generator_state"``)."""
        raise NotImplementedError(f"{type(self).__name__} must implement _saved_configuration()")

    def get_extra_state(self) -> dict[str, Any]:
        """The configuration a checkpoint must match and the generator (``None`` without an own generator)."""
        generator = self.generator
        return {
            **self._saved_configuration(),
            "generator_state": None if generator is None else generator.get_state(),
        }

    def set_extra_state(self, state: Any) -> None:
        """Restore the generator (the configuration is checked before the load, in ``_check_saved``)."""
        saved = state.get("generator_state") if isinstance(state, Mapping) else None
        if saved is None:
            self.generator = None
            return
        generator = torch.Generator()
        generator.set_state(saved.cpu())
        self.generator = generator

    def _check_saved_generator(self, saved: Mapping[str, Any]) -> None:
        """Refuse a saved extra state whose ``"generator_state"`` is neither ``None`` nor a generator's state."""
        generator = saved.get("generator_state")
        if generator is not None and (not isinstance(generator, torch.Tensor) or generator.dtype != torch.uint8):
            raise ValueError(
                f"{type(self).__name__}.load_state_dict: 'generator_state' must be a uint8 tensor "
                f"(torch.Generator.get_state), got {type(generator).__name__}"
            )


class SeedHook:
    """The ``set_seed`` installed on a ``TransformedEnv`` instance: TorchRL's ``set_seed``, then its seeded transforms.

    Called as ``env.set_seed(seed, static_seed=False)``; returns what TorchRL's returns (the next seed).
    Installed by :class:`SeededTransform`; users call ``env.set_seed``, not this class.

    Example:
        >>> from torchrl.envs import TransformedEnv
        >>> from torchtasks.transforms import GoalCommand
        >>> from torchtasks.envs import PendulumEnv
        >>> from torchtasks.transforms import SeedHook
        >>> from torchtasks.spaces import Box
        >>> env = TransformedEnv(PendulumEnv(batch_size=[2]), GoalCommand(Box([-1.0], [1.0])))
        >>> isinstance(env.set_seed, SeedHook)
        True
        >>> env.set_seed(5) == TransformedEnv(PendulumEnv(batch_size=[2])).set_seed(5)  # TorchRL's next seed
        True
    """

    def __init__(self, env: TransformedEnv) -> None:
        if not isinstance(env, TransformedEnv):
            raise TypeError(f"SeedHook: env must be a torchrl TransformedEnv, got {type(env).__name__}")
        self.env = env

    def __call__(self, seed: int | None = None, static_seed: bool = False) -> int | None:
        env = self.env
        checked = None if seed is None else check_int(seed, "env.set_seed: seed")
        next_seed = type(env).set_seed(env, seed, static_seed=static_seed)
        if checked is not None:
            _seed_own_transforms(env, checked)
        return next_seed

    def __repr__(self) -> str:
        return f"{type(self).__name__}(env={type(self.env).__name__})"


def _install_seed_hook(env: object) -> None:
    """Install a :class:`SeedHook` on ``env`` if it is a ``TransformedEnv`` without one (else do nothing)."""
    if not isinstance(env, TransformedEnv):
        return
    hook = env.__dict__.get("set_seed")
    if isinstance(hook, SeedHook) and hook.env is env:
        return
    env.__dict__["set_seed"] = SeedHook(env)


def _chain(env: TransformedEnv) -> list[TransformedEnv]:
    """``env`` and the TransformedEnvs nested below it, innermost first."""
    chain = [env]
    while isinstance(chain[-1].base_env, TransformedEnv):
        chain.append(chain[-1].base_env)
    return chain[::-1]


def _seeded(env: TransformedEnv) -> list[SeededTransform]:
    transform = env.transform
    return [] if transform is None else [t for t in flat_transforms(transform) if isinstance(t, SeededTransform)]


def _seed_own_transforms(env: TransformedEnv, seed: int) -> None:
    """Seed the seeded transforms of ``env`` itself (not of nested envs), indexed after those of nested envs."""
    offset = sum(len(_seeded(inner)) for inner in _chain(env)[:-1])
    for index, transform in enumerate(_seeded(env), start=offset):
        transform.set_seed(derived_seed(seed, index, transform.seed_identity()))


def seed_transforms(env: TransformedEnv, seed: int) -> None:
    """Seed the :class:`SeededTransform`\\ s of ``env`` and its nested ``TransformedEnv``\\ s as ``env.set_seed`` does.

    The base env is not seeded, nor the envs of batched-env workers. Each transform gets
    :func:`derived_seed` of ``seed``, its index among the seeded transforms (innermost env first) and
    its :meth:`~SeededTransform.seed_identity`.

    Example:
        >>> import torch
        >>> from torchrl.envs import TransformedEnv
        >>> from torchtasks.transforms import GoalCommand
        >>> from torchtasks.envs import PendulumEnv
        >>> from torchtasks.transforms import seed_transforms
        >>> from torchtasks.spaces import Box
        >>> env = TransformedEnv(PendulumEnv(batch_size=[3]), GoalCommand(Box([-1.0], [1.0])))
        >>> seed_transforms(env, 7)
        >>> first = env.reset()["goal"]
        >>> seed_transforms(env, 7)
        >>> torch.equal(env.reset()["goal"], first)
        True
    """
    if not isinstance(env, TransformedEnv):
        raise TypeError(f"seed_transforms: env must be a torchrl TransformedEnv, got {type(env).__name__}")
    seed = check_int(seed, "seed_transforms: seed")
    for inner in _chain(env):
        _seed_own_transforms(inner, seed)
