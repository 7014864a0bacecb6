"""JAX set-up shared by every module that traces kernels: float64 everywhere.

hyperoc needs double precision (Newton to near machine precision, Taylor tests of gradients), so
importing a module that builds JAX kernels turns on ``jax_enable_x64``. This is the package's only
global side effect, and it is documented in the README.
"""

import jax

jax.config.update("jax_enable_x64", True)
