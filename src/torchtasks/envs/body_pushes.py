"""The bodies of a MuJoCo model that can be pushed, and the writes of a push into a batch's bound arrays.

A push changes a body's velocity or applies a force to it in every masked simulation at once:
:class:`PushableBodies` resolves a body's name once (a body with a free joint: its six velocity
degrees of freedom; any body: its row of ``xfrc_applied``), checks what a caller gives, and writes
rows of the ``(num_envs, ...)`` arrays ``mujoco.batch.Batch.bind`` returns, with no Python loop over
envs. :class:`~torchtasks.envs.BatchedMujocoEnv` offers these writes as ``add_body_velocity`` and
``set_body_wrench``; the :class:`~torchtasks.transforms.Pushes` transform calls them.

MuJoCo's conventions, kept as they are: a free joint's ``qvel`` is the linear velocity of the body's
origin in the world frame, then the angular velocity in the body's own frame; ``xfrc_applied`` is a
force then a torque, both in the world frame, applied at the body's centre of mass. A state row of the
batch holds ``xfrc_applied`` (``mjSTATE_INTEGRATION``): it persists across steps, a checkpoint of the
env keeps it, and ``mj_resetData`` (an env's reset) clears it.
"""

from __future__ import annotations

import numpy as np
import torch

from torchtasks._checks import check_tensor
from torchtasks._did_you_mean import did_you_mean
from torchtasks._optional import missing_extra

try:
    import mujoco
except ImportError as _error:
    raise missing_extra("mujoco", "torchtasks.envs.body_pushes", _error) from _error

from torchtasks.envs.mujoco_model import object_id, object_names

__all__ = ["PushableBodies"]

#: the values of one push per env: 3 linear then 3 angular components
PUSH_SIZE = 6


class PushableBodies:
    """The bodies of ``model`` that pushes can reach, and checked writes of pushes into bound batch arrays.

    Bodies with a free joint take velocity changes (:meth:`add_velocity`); every named body but the world
    takes a wrench (:meth:`set_wrench`), whose row of ``xfrc_applied`` persists until written again.

    Args:
        model: the compiled model.
        owner: who writes, for the messages (``"BatchedMujocoEnv(quadruped)"``).

    Example:
        >>> import numpy as np, torch
        >>> from torchtasks.envs.mujoco_model import load_model
        >>> model = load_model('<mujoco><worldbody><body name="box"><freejoint/><geom size="0.1"/></body>'
        ...                    '</worldbody></mujoco>')
        >>> bodies = PushableBodies(model, "MyEnv")
        >>> bodies.free_bodies
        ('box',)
        >>> qvel = np.zeros((2, 6))
        >>> delta = torch.ones(2, 6, dtype=torch.float64)
        >>> bodies.add_velocity(qvel, "box", delta, np.array([False, True]))
        >>> qvel.sum(axis=1).tolist()
        [0.0, 6.0]
    """

    def __init__(self, model: mujoco.MjModel, owner: str) -> None:
        self.model = model
        self.owner = owner
        names = object_names(model, "body")
        free = int(mujoco.mjtJoint.mjJNT_FREE)
        #: name -> the address of the body's free joint in qvel
        self._free: dict[str, int] = {}
        for joint in np.flatnonzero(model.jnt_type == free).tolist():
            name = names[int(model.jnt_bodyid[joint])]
            if name:  # an unnamed body cannot be asked for
                self._free[name] = int(model.jnt_dofadr[joint])
        #: the names of the bodies with a free joint, in body order
        self.free_bodies: tuple[str, ...] = tuple(self._free)
        #: name -> id of the bodies a wrench was written to (found once)
        self._ids: dict[str, int] = {}

    def velocity_columns(self, body: object) -> slice:
        """The columns of ``qvel`` of ``body``'s free joint; ``ValueError`` naming the close pushable bodies."""
        address = self._free.get(body) if isinstance(body, str) else None
        if address is not None:
            return slice(address, address + PUSH_SIZE)
        if not isinstance(body, str):
            raise TypeError(f"{self.owner}: body must be a body's name (a str), got {body!r}")
        known = [name for name in object_names(self.model, "body") if name]
        kind = "a body without a free joint" if body in known else "not a body of the model"
        close = [name for name in self.free_bodies if name != body]
        raise ValueError(
            f"{self.owner}: body {body!r} is {kind}; a velocity push needs a body with a free joint"
            f"{did_you_mean(body, close, n=3, cutoff=0.5)} (the pushable bodies: {list(self.free_bodies)})"
        )

    def body_id(self, body: object) -> int:
        """The id of the named body that can take a wrench (any body but the world)."""
        known = self._ids.get(body) if isinstance(body, str) else None
        if known is not None:
            return known
        found = object_id(self.model, "body", body, f"{self.owner}: body")
        if found == 0:
            raise ValueError(f"{self.owner}: body {body!r} is the world, which no force moves")
        self._ids[body] = found  # type: ignore[index]
        return found

    def checked_rows(self, value: object, name: str, mask: np.ndarray) -> np.ndarray:
        """``value`` as float64 ``[num_envs, 6]`` numpy, its rows in ``mask`` finite (else Type/ValueError)."""
        shape = [mask.shape[0], PUSH_SIZE]
        expected = f"a float64 tensor of shape {shape} ([num_envs, 6]: 3 linear, 3 angular components)"
        check_tensor(value, torch.float64, shape, f"{self.owner}: {name}", expected)
        rows = value.numpy(force=True)
        if not np.isfinite(rows).all() and not np.isfinite(rows[mask]).all():  # the whole array first: cheaper
            raise ValueError(f"{self.owner}: {name} must be finite in the rows of the envs in mask")
        return rows

    def add_velocity(self, qvel: np.ndarray, body: str, delta: torch.Tensor, mask: np.ndarray) -> None:
        """``qvel[mask, free joint of body] += delta[mask]``: ``qvel`` a bound ``[num_envs, nv]``, ``mask`` bool."""
        columns = self.velocity_columns(body)
        rows = self.checked_rows(delta, "delta", mask)
        view = qvel[:, columns]
        np.add(view, rows, out=view, where=mask[:, None])

    def set_wrench(self, xfrc_applied: np.ndarray, body: str, wrench: torch.Tensor, mask: np.ndarray) -> None:
        """``xfrc_applied[mask, body] = wrench[mask]``: ``xfrc_applied`` a bound ``[num_envs, nbody, 6]``."""
        index = self.body_id(body)
        rows = self.checked_rows(wrench, "wrench", mask)
        np.copyto(xfrc_applied[:, index], rows, where=mask[:, None])
