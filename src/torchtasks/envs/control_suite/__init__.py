"""The DeepMind Control Suite on the batched MuJoCo engine."""
