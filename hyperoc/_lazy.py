"""Modules imported on first use, so that code which only checks input never starts JAX."""

from __future__ import annotations

import importlib


class LazyModule:
    """Stands for the module ``name``; the first attribute access imports `hyperoc._jax` (float64 and
    JAX's environment, which must come before JAX) and then the module."""

    def __init__(self, name: str):
        self._name, self._module = name, None

    def __getattr__(self, attr: str):
        if self._module is None:
            importlib.import_module("hyperoc._jax")
            self._module = importlib.import_module(self._name)
        return getattr(self._module, attr)


jax = LazyModule("jax")
jnp = LazyModule("jax.numpy")
