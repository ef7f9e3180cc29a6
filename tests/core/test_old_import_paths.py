"""The module paths from before ``torchtasks.transforms`` became a package import the same objects."""

from __future__ import annotations

import importlib

import pytest

import torchtasks.transforms as transforms

OLD_PATHS = {
    "torchtasks.commands": ["GoalCommand"],
    "torchtasks.curriculum": ["Curriculum", "GatedSchedule", "Schedule", "constant", "gated", "linear", "staged"],
    "torchtasks.levels": ["DifficultyLevels", "LevelRule"],
    "torchtasks.seeding": ["SeedHook", "SeededTransform", "derived_seed", "seed_transforms"],
    "torchtasks.checkpoint": ["BaseEnvState", "collector_state", "load_collector_state"],
}


@pytest.mark.quick
@pytest.mark.parametrize("path", sorted(OLD_PATHS))
def test_an_old_path_exports_the_package_objects(path: str) -> None:
    module = importlib.import_module(path)
    assert sorted(module.__all__) == sorted(OLD_PATHS[path])
    for name in OLD_PATHS[path]:
        assert getattr(module, name) is getattr(transforms, name), name


def test_the_package_exports_every_old_name_the_task_transform_domain_randomization_and_the_listing() -> None:
    names = {name for names in OLD_PATHS.values() for name in names}
    names |= {"TaskTransform", "DomainRandomization", "TargetTable", "target_names", "Pushes", "PushableEnv"}
    names |= {"ObservationNoise", "EntryNoise"}
    assert names == set(transforms.__all__)
