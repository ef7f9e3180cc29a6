"""The old path of :mod:`torchtasks.transforms.seeding`: re-exports its public names."""

from torchtasks.transforms.seeding import SeededTransform, SeedHook, derived_seed, seed_transforms

__all__ = ["SeedHook", "SeededTransform", "derived_seed", "seed_transforms"]
