"""Nonlinear and linear solvers: Newton's method, the bordered linear solves, CPU threads."""
