"""The quadrature arrays the kernels close over reach XLA as arguments, not as literals.

Imported before JAX, `hyperoc._jax` sets ``JAX_USE_SIMPLIFIED_JAXPR_CONSTANTS=1`` unless the
environment chooses; as literals, XLA constant-folds products of these arrays at compile time
(seconds each on the Land ventricle, bench/bench_constants.py). JAX reads the variable on import,
so each case runs in a fresh interpreter.
"""

import json
import os
import subprocess
import sys
import textwrap

import pytest

# Three fresh interpreters, each importing JAX and compiling a P2 model: the slow tier.
pytestmark = pytest.mark.slow

#: Lowers the volume of a P2 box model and reports whether the shape-gradient array (nc, nq, nloc, 3)
#: appears as a dense literal of the program, and a digest of the force and volume at a fixed u.
PROGRAM = """
    import hashlib, json
    {first}
    import jax, jax.numpy as jnp, numpy as np
    from hyperoc.mechanics.materials import NeoHookean
    from hyperoc.fem.mesh import box
    from hyperoc.mechanics.model import StateModel

    model = StateModel(box(2), NeoHookean(1.0, 2.0), degree=2)
    u = jnp.asarray(model.interpolate(lambda x: 0.05 * x * x[:, ::-1]))
    text = jax.jit(model.volume).lower(u).as_text()
    shape = "x".join(map(str, model._dN.shape)) + "xf64"
    literal = any(shape in line and "constant" in line and "dense<" in line for line in text.splitlines())
    out = np.concatenate([np.asarray(jax.jit(model.internal_force)(u)), [float(jax.jit(model.volume)(u))]])
    print(json.dumps({"mode": jax.config.values["jax_use_simplified_jaxpr_constants"], "literal": literal,
                      "digest": hashlib.sha256(out.tobytes()).hexdigest()}))
"""


def run(first: str, env_value: str | None = None) -> dict:
    """The program's report in a fresh interpreter that runs ``first`` before anything else."""
    env = {k: v for k, v in os.environ.items() if k != "JAX_USE_SIMPLIFIED_JAXPR_CONSTANTS"}
    if env_value is not None:
        env["JAX_USE_SIMPLIFIED_JAXPR_CONSTANTS"] = env_value
    code = textwrap.dedent(PROGRAM).replace("{first}", first)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=True, env=env)
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def modes():
    return {"hyperoc first": run("import hyperoc"), "jax first": run("import jax"),
            "environment 0": run("import hyperoc", "0")}


def test_importing_hyperoc_first_passes_quadrature_arrays_as_arguments(modes):
    assert modes["hyperoc first"]["mode"] is True
    assert modes["hyperoc first"]["literal"] is False


@pytest.mark.parametrize("case", ["jax first", "environment 0"])
def test_jax_imported_first_or_the_environment_keeps_jax_default(modes, case):
    assert modes[case]["mode"] is False
    assert modes[case]["literal"] is True  # the check above can see a literal when there is one


def test_both_modes_give_bitwise_equal_force_and_volume(modes):
    assert modes["hyperoc first"]["digest"] == modes["jax first"]["digest"] == modes["environment 0"]["digest"]
