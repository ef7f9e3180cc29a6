"""The DeepMind Control Suite's tasks on the batched MuJoCo engine (its models: :mod:`.models`)."""
