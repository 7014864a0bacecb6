"""Checkpointed adjoint (``ReducedFunctional(..., checkpoint_every=k)``) = store-everything adjoint.

The checkpointed forward runs the stepper's own compiled step from the same initial data and with
the same Newton warm start, and the backward pass recomputes every segment the same way, so the
operations are those of the stored run except for (i) XLA compiling a scan of another length (a
one-step scan is inlined and fused differently: round-off, ~1e-16 relative per operation) and (ii)
with the sparse solver, the first factorization of a solver's life uses another ordering than the
later ones, and each solve is only accurate to its backward error ``rtol = 1e-13``. Carried through
the stable linearized recursion these give relative differences of 1e-16 ... 1e-13 (measured: 0
for k >= 2 on the traced path, 1e-14 for k = 1; 5e-14 on the sparse path), so we allow
``RTOL = 5e-13`` (five times the solver's backward error) relative: for J relative to the sum of
the magnitudes of its terms (J itself may be a small difference of larger terms), for the gradient
in the Riesz norm (xi and tau together).
"""

import math
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np
import pytest

from helpers import bar, checkpointing_problem, control_point
from hyperoc import Objective, PressureAt, ReducedFunctional, TimeTransform
from hyperoc.control.objectives import Running
from hyperoc.control.revolve import EveryK, StoreAll
from hyperoc.errors import InputError

RTOL = 5e-13


@dataclass(frozen=True)
class _WholeTrajectory(Running):
    """Uses the whole displacement array: not available with checkpointing."""

    def density(self, traj):
        return jnp.sum(traj.y0 ** 2, axis=1)


def _assert_same(J, m, ks):
    J.schedule = StoreAll()
    value, grad = J.value_and_gradient(m)
    scale = sum(abs(v) for v in J.objective.parts(J.trajectory(J.state(m))).values())
    for k in ks:
        J.schedule = EveryK(k)
        vk, gk = J.value_and_gradient(m)
        ck = J.record(m)
        assert set(ck.levels) == {*range(0, J.N, k), *J.objective_levels}
        assert ck.stored_states <= math.ceil(J.N / k) + len(J.objective_levels)
        assert abs(vk - value) <= RTOL * scale, (k, vk, value, scale)
        assert abs(J(m) - value) <= RTOL * scale, k
        assert J.norm(gk - grad) <= RTOL * J.norm(grad), (k, J.norm(gk - grad) / J.norm(grad))
        assert abs(gk.tau - grad.tau) <= RTOL * J.norm(grad), k


@pytest.mark.slow
def test_traced_1d():
    """Tridiagonal solver (lax.scan path), an objective reading y0(tau) and y1(T)."""
    J = checkpointing_problem("traced-1d")
    assert J.stepper.solver.traced and J.N == 7
    assert J.objective_levels == (3, 7)
    _assert_same(J, control_point(J, 0.75, 0.05), ks=(1, 3, J.N))  # 3 does not divide N = 7 (scans of 3 and 1 steps)


@pytest.mark.slow
def test_python_loop_3d_sparse():
    """Sparse LU solver (jitted step driven from Python) on a 3D box."""
    J = checkpointing_problem("sparse-3d")
    assert not J.stepper.solver.traced and J.N == 7
    _assert_same(J, control_point(J, 0.3, 0.5), ks=(1, 3, J.N))  # 3 does not divide N = 7


def test_whole_trajectory_objective_is_refused():
    J = ReducedFunctional(bar(8), TimeTransform.for_step(1.0, 0.25, 0.5),
                          Objective(running=(_WholeTrajectory(),), at_tau=PressureAt()), schedule=EveryK(2))
    with pytest.raises(InputError, match="whole arrays"):
        J(J.zero(0.5))
    for bad in (0, 1.5, True):
        with pytest.raises(InputError, match="checkpoint_every"):
            EveryK(bad)


def test_state_after_the_gradient_reuses_its_forward_solve():
    """The whole trajectory at a point whose value and gradient were computed is read from their
    record when it keeps every level (no checkpointing): bit for bit the trajectory of a fresh solve,
    and no further solve; with checkpoints the record does not hold it, and the state costs one solve."""
    J = checkpointing_problem("traced-1d")
    m = control_point(J, 0.75, 0.04, seed=11)  # a point no other test evaluates: not cached yet
    before = J.counts["state"]
    J.value_and_gradient(m)
    sol = J.state(m)
    assert J.counts["state"] == before + 1
    fresh = J.stepper.run(J.transform.grid(m.tau), m.xi, diagnose=False)
    for name in ("t", "y0", "y1", "p_steps", "pressure", "volume", "newton_iterations", "min_det_F", "max_grad", "xi"):
        assert np.array_equal(getattr(sol, name), getattr(fresh, name)), name
    J.schedule = EveryK(3)
    other = control_point(J, 0.75, 0.04, seed=12)
    J.value_and_gradient(other)
    J.state(other)
    assert J.counts["state"] == before + 3
