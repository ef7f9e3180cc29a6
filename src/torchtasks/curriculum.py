"""The old path of :mod:`torchtasks.transforms.curriculum` and :mod:`torchtasks.transforms.schedules` (re-exports)."""

from torchtasks.transforms.curriculum import Curriculum
from torchtasks.transforms.schedules import GatedSchedule, Schedule, constant, gated, linear, staged

__all__ = ["Curriculum", "GatedSchedule", "Schedule", "constant", "gated", "linear", "staged"]
