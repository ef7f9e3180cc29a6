"""A batched, differentiable 2-D point mass in a box, in torch, whose reward and termination come from a task."""

from __future__ import annotations

from collections.abc import Sequence

import torch

from torchtasks.envs._state_env import StateEnv

__all__ = ["PointMassEnv", "point_mass_dynamics"]


def point_mass_dynamics(
    state: torch.Tensor,
    force: torch.Tensor,
    *,
    dt: float = 0.05,
    damping: float = 0.5,
    bound: float = 1.0,
) -> torch.Tensor:
    """Return the next ``[x, y, vx, vy]`` of a unit point mass in the box ``[-bound, bound]²``, semi-implicit Euler.

    ``v ← v + dt·(F − damping·v)``, then ``p ← p + dt·v``. A position that would leave the box is
    clamped to the wall and the velocity component into the wall is set to zero (an inelastic
    wall). Pure, batched and differentiable (``state [*B, 4]``, ``force [*B, 2]``; away from the
    walls the gradient is the linear map of the Euler step, at a wall the blocked component has
    zero gradient).

    Example:
        >>> import torch
        >>> point_mass_dynamics(torch.zeros(1, 4), torch.tensor([[1.0, -1.0]]))
        tensor([[ 0.0025, -0.0025,  0.0500, -0.0500]])
    """
    position, velocity = state[..., :2], state[..., 2:]
    velocity = velocity + dt * (force - damping * velocity)
    position = position + dt * velocity
    clamped = position.clamp(-bound, bound)
    velocity = torch.where(clamped != position, torch.zeros_like(velocity), velocity)
    return torch.cat((clamped, velocity), dim=-1)


class PointMassEnv(StateEnv):
    """A batch of force-driven 2-D point masses in a box, simulated in torch, for goal-reaching tasks.

    The observation is the raw state ``[x, y, vx, vy]``; the action is a 2-D force, clipped to
    ``±max_force`` per axis. Positions stay in ``[-bound, bound]²`` (inelastic walls, see
    :func:`point_mass_dynamics`); resets draw the position uniformly in the box with zero velocity.
    The env pays no reward and never ends an episode by itself: put a
    :class:`~torchtasks.transforms.TaskTransform` (and a ``StepCounter``) on it, e.g. with a
    :class:`~torchtasks.transforms.GoalCommand` and a task reaching the goal position (the state
    entries ``"x"``, ``"y"``). The dynamics are differentiable, so ``env.rollout`` keeps the autograd
    graph from the policy's actions to the states and the task's rewards.

    Args:
        batch_size: number of point masses (any shape).
        dt: time step [s].
        max_force: force bound per axis (the action is clipped to ``±max_force``).
        damping: linear velocity damping (the terminal speed per axis is ``max_force / damping``).
        bound: half-width of the box.
        seed: seed of the env's own random generator.
        dtype, device: where and in which precision the state lives.

    Example:
        >>> import torch
        >>> env = PointMassEnv(batch_size=[3], seed=0)
        >>> td = env.rand_step(env.reset())
        >>> td["next", "observation"].shape
        torch.Size([3, 4])
    """

    #: the names of the state entries (for ``EnvSpec``/``MaskedTask`` selections)
    labels = ("x", "y", "vx", "vy")

    def __init__(
        self,
        batch_size: Sequence[int] | torch.Size = (),
        *,
        dt: float = 0.05,
        max_force: float = 1.0,
        damping: float = 0.5,
        bound: float = 1.0,
        seed: int | None = None,
        dtype: torch.dtype = torch.float32,
        device: torch.device | str | None = None,
    ) -> None:
        if not (dt > 0 and max_force > 0 and damping >= 0 and bound > 0):
            raise ValueError(
                f"PointMassEnv needs dt > 0, max_force > 0, damping >= 0 and bound > 0, got dt={dt}, "
                f"max_force={max_force}, damping={damping}, bound={bound}"
            )
        super().__init__(
            batch_size,
            state_size=4,
            action_size=2,
            action_bound=float(max_force),
            dtype=dtype,
            device=device,
            seed=seed,
        )
        self.dt = float(dt)
        self.max_force = float(max_force)
        self.damping = float(damping)
        self.bound = float(bound)

    def _sample_state(self) -> torch.Tensor:
        uniform = torch.rand((*self.batch_size, 2), generator=self.rng, device=self.rng.device, dtype=self.dtype_)
        position = (2 * uniform - 1) * self.bound
        return torch.cat((position, torch.zeros_like(position)), dim=-1).to(self.device or "cpu")

    def _next_state(self, state: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        force = action.clamp(-self.max_force, self.max_force)
        return point_mass_dynamics(state, force, dt=self.dt, damping=self.damping, bound=self.bound)
