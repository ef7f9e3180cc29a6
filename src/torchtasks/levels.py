"""The old path of :mod:`torchtasks.transforms.levels`: re-exports its public names."""

from torchtasks.transforms.levels import DifficultyLevels, LevelRule

__all__ = ["DifficultyLevels", "LevelRule"]
