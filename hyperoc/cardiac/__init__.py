"""Cardiac mechanics: the benchmarks (Land et al. 2015, Aróstica et al. 2025) and the indices of a beat."""
