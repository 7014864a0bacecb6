"""Optimal control: objectives, the exact adjoint and its checkpointing, the reduced functional,
the control space, optimizers and Taylor tests."""
