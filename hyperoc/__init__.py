"""hyperoc: optimal control of damped hyperelastic bodies under a global volume constraint."""
