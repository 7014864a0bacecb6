"""JAX set-up shared by every module that traces kernels: float64 everywhere.

hyperoc needs double precision (Newton to near machine precision, Taylor tests of gradients), so
importing a module that builds JAX kernels turns on ``jax_enable_x64``; in a process pinned to one
CPU it also starts the CPU backend with a thread pool of at least two threads
(`hyperoc.threads.start_backend`: with one, host solves can deadlock). These are the package's only
global side effects, and they are documented in the README.
"""

import jax

from .threads import start_backend

jax.config.update("jax_enable_x64", True)
start_backend()
