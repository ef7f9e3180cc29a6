"""The old path of :mod:`torchtasks.transforms.checkpoint`: re-exports its public names."""

from torchtasks.transforms.checkpoint import BaseEnvState, collector_state, load_collector_state

__all__ = ["BaseEnvState", "collector_state", "load_collector_state"]
