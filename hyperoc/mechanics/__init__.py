"""The mechanics: strain energies, controls, fibres, loads, and the discrete state models."""
