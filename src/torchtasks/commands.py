"""The old path of :mod:`torchtasks.transforms.command`: re-exports its public names."""

from torchtasks.transforms.command import GoalCommand

__all__ = ["GoalCommand"]
