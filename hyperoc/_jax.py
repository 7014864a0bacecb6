"""JAX set-up shared by every module that traces kernels: float64 everywhere.

hyperoc needs double precision (Newton to near machine precision, Taylor tests of gradients), so
importing a module that builds JAX kernels turns on ``jax_enable_x64``; in a process pinned to one
CPU it also starts the CPU backend with a thread pool of at least two threads
(`hyperoc.threads.start_backend`: with one, host solves can deadlock).

When it is imported before JAX (``import hyperoc`` first, the CLI, the bench scripts, the tests),
it also sets ``JAX_USE_SIMPLIFIED_JAXPR_CONSTANTS=1`` unless the environment already chooses: the
kernels close over the mesh's quadrature arrays (shape gradients, weights, gather indices: 0.1 GB
each at 80k dofs), and in JAX's default mode XLA receives them as literals of the program and
constant-folds products of them at compile time ("Constant folding an instruction is taking > 1s");
in this mode they are passed as arguments. JAX reads the variable when it is imported, so after
``import jax`` it is left alone. Results are bitwise the same; compilation is faster and needs less
memory, for a slightly slower kernel evaluation (``python bench/bench_constants.py``; the docs'
performance page).

These are the package's only global side effects, and they are documented in the docs.
"""

import os
import sys

if "jax" not in sys.modules:
    os.environ.setdefault("JAX_USE_SIMPLIFIED_JAXPR_CONSTANTS", "1")

import jax  # noqa: E402  (after the environment variable, which JAX reads on import)

from .threads import start_backend  # noqa: E402

jax.config.update("jax_enable_x64", True)
start_backend()
