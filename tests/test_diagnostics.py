"""The model's state diagnostics (`hyperoc.mechanics.diagnostics` through `StateModel`)."""

import numpy as np

from hyperoc.fem.mesh import box
from hyperoc.mechanics import diagnostics
from hyperoc.mechanics.materials import HolzapfelOgden
from hyperoc.mechanics.model import StateModel


def _turning_frames(x):
    """Fibres in the (x, y) plane turning with x + 2 y, sheets along z: a frame that varies inside every cell."""
    a = x[..., 0] + 2.0 * x[..., 1]
    f = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=-1)
    s = np.broadcast_to([0.0, 0.0, 1.0], f.shape)
    return np.stack([f, s, np.cross(f, s)], axis=-2)


def test_the_acoustic_check_over_cell_chunks_is_the_check_over_all_points_at_once():
    """`StateModel.min_acoustic_eigenvalues` takes the acoustic tensors of `map_cells`' chunks of cells one
    chunk at a time (a whole P2 ventricle's at once take gigabytes); per state, its minimum is the one over
    all points at once: the same numbers, chunked (here 5 cells a chunk: several chunks and a remainder)."""
    model = StateModel(box(2, 2, 1), HolzapfelOgden(bulk_modulus=30.0), degree=2, frames=_turning_frames,
                       dirichlet=None)
    model.tangent_chunk_points = 5 * model._w.shape[1]
    assert len(model.mesh.cells) % 5 and len(model.mesh.cells) > 10
    rng = np.random.default_rng(0)
    states = 0.02 * rng.standard_normal((3, model.n))
    whole = [float(diagnostics.min_acoustic_eigenvalue(model.material.energy_of_F, model.deformation_gradient(u),
                                                       model.material_frames)) for u in states]
    np.testing.assert_allclose(model.min_acoustic_eigenvalues(states), whole, rtol=1e-12)
    assert min(whole) < max(whole)  # the states differ: the check is not of one repeated value
