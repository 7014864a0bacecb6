"""Cardiac mechanics benchmarks (Land et al. 2015)."""
