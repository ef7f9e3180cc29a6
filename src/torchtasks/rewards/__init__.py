"""Reward functions: ``torch.nn.Module``\\ s on batched tensors, differentiable end to end.

Stateless rewards are called as ``reward(error_state, error_action) -> Tensor[*B]``. Every reward
also follows the functional memory protocol (``reset`` / ``step``) so that stateful ones (the
forward-velocity family) compose with tasks the same way.
"""

from torchtasks.rewards.action_rate import ActionRateReward
from torchtasks.rewards.air_time import FeetAirTimeReward
from torchtasks.rewards.base import RewardFunction
from torchtasks.rewards.compound import CompoundReward
from torchtasks.rewards.constant import ConstantReward
from torchtasks.rewards.contact_count import ContactCountReward
from torchtasks.rewards.cosine import CosineReward, ShiftedCosineReward
from torchtasks.rewards.error import (
    AbsoluteErrorReward,
    ExpQuadraticErrorReward,
    QuadraticErrorReward,
    ScaledExpQuadraticErrorReward,
)
from torchtasks.rewards.locomotion import AntForwardReward, ForwardVelocityReward, HumanoidForwardReward
from torchtasks.rewards.product import AffineReward, ProductReward, hamacher_product
from torchtasks.rewards.squared_sum import SquaredSumReward
from torchtasks.rewards.state_function import StateFunctionReward
from torchtasks.rewards.swing_up import CartPoleSwingUpReward, SwingUpReward
from torchtasks.rewards.terms import (
    AboveThresholdIndicator,
    ContactCostReward,
    ControlCostReward,
    DisplacementReward,
    HealthyReward,
    VelocityReward,
)
from torchtasks.rewards.tolerance import SIGMOIDS, ToleranceReward, tolerance
from torchtasks.rewards.tracking import ExpTrackingReward

__all__ = [
    "SIGMOIDS",
    "AboveThresholdIndicator",
    "AbsoluteErrorReward",
    "ActionRateReward",
    "AffineReward",
    "AntForwardReward",
    "CartPoleSwingUpReward",
    "CompoundReward",
    "ConstantReward",
    "ContactCostReward",
    "ContactCountReward",
    "ControlCostReward",
    "CosineReward",
    "DisplacementReward",
    "ExpQuadraticErrorReward",
    "ExpTrackingReward",
    "FeetAirTimeReward",
    "ForwardVelocityReward",
    "HealthyReward",
    "HumanoidForwardReward",
    "ProductReward",
    "QuadraticErrorReward",
    "RewardFunction",
    "ScaledExpQuadraticErrorReward",
    "ShiftedCosineReward",
    "SquaredSumReward",
    "StateFunctionReward",
    "SwingUpReward",
    "ToleranceReward",
    "VelocityReward",
    "hamacher_product",
    "tolerance",
]
