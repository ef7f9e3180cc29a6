"""dm_control's tolerance kernel on tensors: :func:`tolerance` and the reward :class:`ToleranceReward`.

``tolerance(x, bounds, margin, sigmoid, value_at_margin)`` is a soft indicator of ``x`` lying in
``[lower, upper]``: 1 inside, falling off outside with one of eight sigmoids so that it equals
``value_at_margin`` at a distance ``margin`` from the nearest bound (0 outside when ``margin == 0``).
It has the semantics and the argument names of ``dm_control.utils.rewards.tolerance``, which
dm_control, MuJoCo Playground and Meta-World build their rewards from, and works on tensors of any
shape, with per-entry (per-env) bounds and margins, on any device, differentiably (the output is always on
the graph, with finite gradients for every non-NaN input: see :func:`tolerance`) and under
``torch.compile(fullgraph=True)``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import torch

from torchtasks._checks import SUPPORTED_FLOATS, as_constant, cast_like, check_finite_scalar, check_input, check_int
from torchtasks.rewards.base import RewardFunction, check_ignored_action, index_problem
from torchtasks.spaces import Box

__all__ = ["SIGMOIDS", "ToleranceReward", "tolerance"]

#: the value of :func:`tolerance` at ``margin`` distance from the bounds unless told otherwise (dm_control's)
DEFAULT_VALUE_AT_MARGIN = 0.1
#: the sigmoids :func:`tolerance` knows
SIGMOIDS = ("gaussian", "hyperbolic", "long_tail", "reciprocal", "cosine", "linear", "quadratic", "tanh_squared")
#: sigmoids that reach 0 at a finite distance, so ``value_at_margin`` may be 0 for them
_COMPACT = ("cosine", "linear", "quadratic")

Bound = float | torch.Tensor


def _check_sigmoid(sigmoid: str) -> None:
    if sigmoid not in SIGMOIDS:
        raise ValueError(f"Unknown sigmoid type {sigmoid!r}; valid sigmoids are {list(SIGMOIDS)}")


def _check_value_at_margin(value_at_margin: float, sigmoid: str) -> float:
    _check_sigmoid(sigmoid)
    value = check_finite_scalar(value_at_margin, "value_at_margin")
    if sigmoid in _COMPACT:
        if not 0 <= value < 1:
            raise ValueError(f"`value_at_1` must be nonnegative and smaller than 1, got {value}.")
    elif not 0 < value < 1:
        raise ValueError(f"`value_at_1` must be strictly between 0 and 1, got {value}.")
    return value


def _scale(sigmoid: str, value_at_1: float) -> float:
    """The factor that makes the sigmoid equal ``value_at_1`` at 1 (dm_control's formulas)."""
    if sigmoid == "gaussian":
        return math.sqrt(-2 * math.log(value_at_1))
    if sigmoid == "hyperbolic":
        return math.acosh(1 / value_at_1)
    if sigmoid == "long_tail":
        return math.sqrt(1 / value_at_1 - 1)
    if sigmoid == "reciprocal":
        return 1 / value_at_1 - 1
    if sigmoid == "cosine":
        return math.acos(2 * value_at_1 - 1) / math.pi
    if sigmoid == "linear":
        return 1 - value_at_1
    if sigmoid == "quadratic":
        return math.sqrt(1 - value_at_1)
    # tanh_squared: below ~1.1e-16, 1 - value_at_1 rounds to 1 and atanh(1) is infinite; numpy's arctanh
    # (dm_control's) returns inf, math.atanh raises a bare "math domain error"
    root = math.sqrt(1 - value_at_1)
    return math.inf if root >= 1 else math.atanh(root)


def _sigmoid(d: torch.Tensor, sigmoid: str, scale: float) -> torch.Tensor:
    """The sigmoid of a distance ``d >= 0`` (in units of the margin), written so gradients stay finite.

    ``d * scale`` must not overflow where the result is used (:func:`_tolerance` sets such distances aside).
    """
    if scale > torch.finfo(d.dtype).max:
        # a value_at_margin so small that the scale is infinite (tanh_squared below ~1.1e-16: atanh(1) = inf;
        # hyperbolic, long_tail and reciprocal below ~5.6e-309: 1 / value_at_margin overflows), or beyond
        # d's dtype (long_tail, reciprocal in float32). dm_control's sigmoid of d * scale is then 0 for d > 0,
        # and at d == 0 1 (a finite scale) or NaN (0 * inf); the same values, without d * inf (whose gradient is
        # 0 * inf = NaN), NaN for a NaN d, and on d's graph with a zero gradient
        zero = torch.zeros((), dtype=d.dtype, device=d.device)
        at_zero = torch.full((), math.nan if math.isinf(scale) else 1.0, dtype=d.dtype, device=d.device)
        return torch.where(d > 0, zero, at_zero) + d * 0
    z = d * scale
    if sigmoid == "gaussian":
        return torch.exp(-0.5 * z * z)
    if sigmoid == "hyperbolic":
        # 1 / cosh(z) without cosh's overflow (whose gradient is inf / inf)
        decay = torch.exp(-z.abs())
        return 2 * decay / (1 + decay * decay)
    if sigmoid == "long_tail":
        return 1 / (z * z + 1)
    if sigmoid == "reciprocal":
        return 1 / (z.abs() + 1)
    if sigmoid == "tanh_squared":
        return 1 - torch.tanh(z) ** 2
    inside = z.abs() < 1
    zero = torch.zeros((), dtype=z.dtype, device=z.device)
    # the compact sigmoids: z is set to 0 outside *before* the formula, so that where() passes finite gradients
    # also where pi * z overflows (cos and sin of inf are NaN)
    z = torch.where(inside, z, zero)
    if sigmoid == "cosine":
        return torch.where(inside, (1 + torch.cos(math.pi * z)) / 2, zero)
    if sigmoid == "linear":
        return torch.where(inside, 1 - z, zero)
    return torch.where(inside, 1 - z * z, zero)  # quadratic


def _as_bound(value: Bound, like: torch.Tensor) -> torch.Tensor:
    if isinstance(value, torch.Tensor):
        return cast_like(value, like)
    return torch.tensor(float(value), dtype=like.dtype, device=like.device)


def _check_bounds(lower: Bound, upper: Bound, margin: Bound) -> None:
    """dm_control's argument errors (on the host: for tensors, outside ``torch.compile`` only)."""
    if torch.compiler.is_compiling():
        return
    lower_t, upper_t = torch.as_tensor(lower), torch.as_tensor(upper)
    if bool(torch.isnan(lower_t).any()) or bool(torch.isnan(upper_t).any()):
        raise ValueError(f"bounds must not be NaN, got bounds=({lower!r}, {upper!r}).")
    if bool((lower_t > upper_t).any()):
        raise ValueError(f"Lower bound must be <= upper bound, got bounds=({lower!r}, {upper!r}).")
    margin_t = torch.as_tensor(margin)
    if bool((margin_t < 0).any()) or bool(torch.isnan(margin_t).any()):
        raise ValueError(f"`margin` must be non-negative, got {margin!r}.")


def _indicator(x: torch.Tensor, lower: torch.Tensor, upper: torch.Tensor) -> torch.Tensor:
    """The 0/1 indicator of the bounds (``margin == 0``), on the graph of ``x`` and the bounds (gradients 0)."""
    in_bounds = (lower <= x) & (x <= upper)
    one = torch.ones((), dtype=x.dtype, device=x.device)
    zero = torch.zeros((), dtype=x.dtype, device=x.device)
    distance = torch.where(x < lower, lower - x, x - upper)
    # a zero built from the distance keeps the output on the graph (backward works); nan_to_num keeps it exact
    # and its gradient 0 at ±inf/NaN
    return torch.where(in_bounds, one, zero) + distance.nan_to_num(0.0, 0.0, 0.0) * 0


def _tolerance(
    x: torch.Tensor, lower: torch.Tensor, upper: torch.Tensor, margin: torch.Tensor | float, sigmoid: str, scale: float
) -> torch.Tensor:
    """The kernel on already-checked tensor arguments (``margin`` a tensor or a Python number)."""
    if isinstance(margin, (int, float)) and margin == 0:
        return _indicator(x, lower, upper)
    in_bounds = (lower <= x) & (x <= upper)
    one = torch.ones((), dtype=x.dtype, device=x.device)
    zero = torch.zeros((), dtype=x.dtype, device=x.device)
    distance = torch.where(x < lower, lower - x, x - upper)
    positive: torch.Tensor | None = None
    if isinstance(margin, torch.Tensor):
        positive = margin > 0
        margin = torch.where(positive, margin, one)
    # Inside the bounds, and where the distance or the scaled distance is infinite (x = ±inf beyond a finite
    # bound, or an overflow), the distance is replaced by 0 *before* the division and the sigmoid, whose
    # derivatives there would be 0 * inf = NaN (the "double where"); those far entries get the sigmoid's limit:
    # 0, or NaN for inf / inf (x = ±inf with an infinite margin) as dm_control's (the compact sigmoids give 0).
    raw = distance / margin
    far = torch.isinf(distance) | torch.isinf(raw * scale)
    distance = torch.where(in_bounds | far, zero, distance)
    value = _sigmoid(distance / margin, sigmoid, scale)
    if sigmoid in _COMPACT:
        far_value = zero
    else:
        far_value = torch.where(torch.isnan(raw), torch.full((), math.nan, dtype=x.dtype, device=x.device), zero)
    value = torch.where(far, far_value, value)
    if positive is not None:
        value = torch.where(positive, value, zero)
    return torch.where(in_bounds, one, value)


def tolerance(
    x: torch.Tensor,
    bounds: tuple[Bound, Bound] = (0.0, 0.0),
    margin: Bound = 0.0,
    sigmoid: str = "gaussian",
    value_at_margin: float = DEFAULT_VALUE_AT_MARGIN,
) -> torch.Tensor:
    """Return 1 where ``x`` lies in ``bounds`` and a value falling to 0 with the distance outside (dm_control's).

    Args:
        x: a floating tensor of any shape.
        bounds: inclusive ``(lower, upper)``; numbers or tensors broadcastable to ``x`` (per entry, per
            env); may be infinite, or equal for an exact target.
        margin: how far outside the bounds the output has fallen to ``value_at_margin``; a number or a
            tensor broadcastable to ``x``. 0 gives the 0/1 indicator of the bounds.
        sigmoid: the shape of the fall-off, one of :data:`SIGMOIDS`: ``gaussian``, ``hyperbolic``,
            ``long_tail``, ``reciprocal`` (never reach 0), ``cosine``, ``linear``, ``quadratic`` (reach
            0 at a finite distance), ``tanh_squared``.
        value_at_margin: the output at ``margin`` distance from the bounds; in ``(0, 1)``, or ``[0, 1)``
            for the compact sigmoids (not checked with a number ``margin`` of 0, as dm_control).

    Returns:
        a tensor of the broadcast shape of ``x``, the bounds and the margin, in ``x``'s dtype and device,
        with values in ``[0, 1]``; NaN only where dm_control's value is NaN too: for a NaN ``x`` (with
        ``margin > 0``; the compact sigmoids give 0), for ``x = ±inf`` beyond a finite bound with an infinite
        margin (inf / inf; the compact sigmoids give 0), and outside the bounds where the distance over the
        margin is exactly 0 (an infinite margin, or an underflow) when the sigmoid's scale is infinite
        (``tanh_squared`` with ``value_at_margin`` below ~1.1e-16, ``hyperbolic``, ``long_tail`` and
        ``reciprocal`` below ~5.6e-309: dm_control's 0 * inf).

    Note:
        Gradients. The output is on the graph of ``x``, the bounds and a tensor margin even where it is
        constant (also for ``margin=0``), so ``backward()`` always works. For every non-NaN ``x``, finite or
        infinite bounds, margins in ``[0, inf]`` and every allowed ``value_at_margin``, the gradients with
        respect to ``x`` and the bounds are finite: 0 where the output is flat (inside the bounds, with ``margin=0``, at
        ``x = ±inf``, where the sigmoid's argument overflows, and everywhere with an infinite scale), and one
        of the one-sided derivatives at the bounds and at the ends of the compact sigmoids. The gradient with
        respect to a tensor margin is finite as well, unless ``distance / margin**2`` overflows the dtype (a
        margin tiny against the distance, which autograd's division rule then turns into 0 * inf).

    Raises:
        ValueError: as dm_control: ``lower > upper``, a negative margin, ``value_at_margin`` outside the
            range its sigmoid allows, or an unknown sigmoid (the message lists the valid ones).

    Example:
        >>> import torch
        >>> x = torch.tensor([0.5, 1.0, 2.0, 3.0], dtype=torch.float64)
        >>> tolerance(x, bounds=(0.0, 1.0), margin=1.0, sigmoid="linear", value_at_margin=0.0)
        tensor([1., 1., 0., 0.], dtype=torch.float64)
        >>> tolerance(x, bounds=(0.0, 1.0), margin=1.0)[2]  # gaussian: 0.1 at one margin outside
        tensor(0.1000, dtype=torch.float64)
    """
    if not isinstance(x, torch.Tensor) or x.dtype not in SUPPORTED_FLOATS:
        got = x.dtype if isinstance(x, torch.Tensor) else type(x).__name__
        raise TypeError(f"x must be a float32 or float64 torch.Tensor (half precision is not supported), got {got}")
    if not (isinstance(bounds, (tuple, list)) and len(bounds) == 2):
        raise ValueError(f"bounds must be a (lower, upper) pair, got {bounds!r}")
    lower, upper = bounds
    _check_bounds(lower, upper, margin)
    if not isinstance(margin, torch.Tensor) and float(margin) == 0:
        # as dm_control: the sigmoid's value_at_margin plays no part in the indicator, so it is not checked
        _check_sigmoid(sigmoid)
        return _indicator(x, _as_bound(lower, x), _as_bound(upper, x))
    scale = _scale(sigmoid, _check_value_at_margin(value_at_margin, sigmoid))
    margin_value = cast_like(margin, x) if isinstance(margin, torch.Tensor) else float(margin)
    return _tolerance(x, _as_bound(lower, x), _as_bound(upper, x), margin_value, sigmoid, scale)


class ToleranceReward(RewardFunction):
    """dm_control-style tolerance of chosen entries of the state error, combined by product or mean.

    The reward of a row is ``combine_i tolerance(e_s[..., i], (lower_i, upper_i), margin_i, sigmoid,
    value_at_margin)`` over the selected entries ``i``: in ``[0, 1]``, 1 when every selected entry
    lies in its bounds. In a :class:`~torchtasks.tasks.DesiredStateTask` the input is the error
    ``state_des - state`` (bounds around 0 say "close to the goal"); in a
    :class:`~torchtasks.tasks.GoallessTask` it is the raw state (bounds say "in this range", e.g. an
    upright torso height). The action is ignored.

    Args:
        bounds: ``(lower, upper)``: numbers, or one number per selected entry.
        margin: a number or one per selected entry (0: the indicator of the bounds).
        sigmoid: one of :data:`SIGMOIDS`.
        value_at_margin: the value at ``margin`` outside the bounds.
        indices: the entries to read (ints, or labels of ``space``); ``None`` reads all.
        space: a :class:`~torchtasks.spaces.Box` whose labels name the entries in ``indices``.
        combine: ``"product"`` (all entries must be in bounds, dm_control's way of requiring several
            conditions) or ``"mean"``.
        learnable: make the bounds and margins trainable ``nn.Parameter``\\ s instead of buffers.

    Example:
        >>> import torch
        >>> from torchtasks.rewards import ToleranceReward
        >>> upright = ToleranceReward(bounds=(1.2, float("inf")), margin=0.6, sigmoid="linear",
        ...                           value_at_margin=0.0, indices=[0])
        >>> upright(torch.tensor([[1.5, 0.0], [0.9, 0.0], [0.3, 0.0]]), None)
        tensor([1.0000, 0.5000, 0.0000])
    """

    uses_action = False

    def __init__(
        self,
        bounds: tuple[float | Sequence[float], float | Sequence[float]] = (0.0, 0.0),
        margin: float | Sequence[float] = 0.0,
        sigmoid: str = "gaussian",
        value_at_margin: float = DEFAULT_VALUE_AT_MARGIN,
        *,
        indices: Iterable[int | str] | None = None,
        space: Box | None = None,
        combine: str = "product",
        learnable: bool = False,
    ) -> None:
        super().__init__()
        if not (isinstance(bounds, (tuple, list)) and len(bounds) == 2):
            raise ValueError(f"bounds must be a (lower, upper) pair, got {bounds!r}")
        self.value_at_margin = _check_value_at_margin(value_at_margin, sigmoid)
        self.scale = _scale(sigmoid, self.value_at_margin)
        self.sigmoid = sigmoid
        if combine not in ("product", "mean"):
            raise ValueError(f"combine must be 'product' or 'mean', got {combine!r}")
        self.combine = combine
        if space is not None and not isinstance(space, Box):
            raise TypeError(f"space must be a torchtasks.spaces.Box or None, got {type(space).__name__}")
        if indices is None:
            self.indices: list[int] | None = None
        elif space is not None:
            self.indices = space.indices(indices)
        else:
            indices = list(indices)
            if any(isinstance(index, str) for index in indices):
                raise TypeError(f"indices name labels, {indices}: pass the space they label (space=...)")
            self.indices = [check_int(index, f"indices[{i}]") for i, index in enumerate(indices)]
            if not self.indices:
                raise ValueError("indices must name at least one entry (or be None for all)")
        lower = as_constant(bounds[0], "bounds[0]", ndim=(0, 1)).reshape(-1)
        upper = as_constant(bounds[1], "bounds[1]", ndim=(0, 1)).reshape(-1)
        margin_t = as_constant(margin, "margin", ndim=(0, 1)).reshape(-1)
        sizes = {t.numel() for t in (lower, upper, margin_t)} - {1}
        if len(sizes) > 1 or (self.indices is not None and sizes and sizes != {len(self.indices)}):
            raise ValueError(
                f"bounds and margin must be numbers or have one entry per selected entry "
                f"({'all' if self.indices is None else len(self.indices)}), got sizes "
                f"{lower.numel()}, {upper.numel()} and {margin_t.numel()}"
            )
        self.size = sizes.pop() if sizes else None
        _check_bounds(lower, upper, margin_t)
        self._register_constant("lower", lower, learnable)
        self._register_constant("upper", upper, learnable)
        self._register_constant("margin", margin_t, learnable)

    def _size_problem(self, state_size: int, action_size: int | None, who: str) -> str | None:
        if self.indices is not None:
            for index in self.indices:
                problem = index_problem(who, "indices", index, state_size)
                if problem is not None:
                    return problem
            return None
        if self.size is not None and self.size != state_size:
            return f"{who} has bounds for {self.size} entries, but the task's state has {state_size} entries"
        return None

    def forward(self, error_state: torch.Tensor, error_action: torch.Tensor | None = None) -> torch.Tensor:
        check_input(error_state, "error_state")
        problem = self._size_problem(error_state.shape[-1], None, f"reward {type(self).__name__}")
        if problem is not None:
            raise ValueError(problem.replace("the task's state", "error_state"))
        check_ignored_action(error_state, error_action)
        return self._value(error_state, error_action)

    def _value(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        x = error_state if self.indices is None else error_state[..., self.indices]
        values = _tolerance(
            x, cast_like(self.lower, x), cast_like(self.upper, x), cast_like(self.margin, x), self.sigmoid, self.scale
        )
        return values.prod(dim=-1) if self.combine == "product" else values.mean(dim=-1)

    def extra_repr(self) -> str:
        return f"sigmoid={self.sigmoid!r}, value_at_margin={self.value_at_margin}, combine={self.combine!r}"
