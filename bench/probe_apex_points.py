"""Where the ventricle benchmarks converge and where they do not: the deformed z of fixed material
points near the apexes, read from the nested levels that ``bench_land.py --save-states`` wrote.

The vertices of level 0 are vertices of every finer level (uniform refinement keeps them, first in
the numbering), so their deformed positions form convergence sequences like the apexes'. Printed per
level: the endocardial and epicardial apex z, the z of the ``--ring`` level-0 vertices of each wall
nearest to its apex (with their distance from the long axis), min det F and where it is (distance rho
from the long axis and z, reference configuration; and from the endocardial apex), and for problem 3
the fibre-strain extremes. Then, per tracked point, the changes between levels and the ratio of the
last two (a converging sequence of order k gives ~2^k; a point singularity gives ~1 at the apex,
converging rings around it).

    python bench/bench_land.py --problems 3 ... --save-states results/states   # the solves
    nice taskset -c 0 python bench/probe_apex_points.py results/states/p3-h6-kappainf-clamped-L{0,1,2}.npz
"""

from __future__ import annotations

import argparse
import gc

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from hyperoc.active import FibreTension  # first: hyperoc sets JAX's environment
from hyperoc.benchmarks import CONTRACTION, VENTRICLE, load_state, node_position
from hyperoc.errors import InputError
from hyperoc.materials import det

APEXES = {"endocardium": np.array(VENTRICLE["endo_apex"]), "epicardium": np.array(VENTRICLE["epi_apex"])}


def nearest_wall_vertices(model, wall: str, apex, count: int) -> np.ndarray:
    """The ``count`` vertices of ``wall`` (of this level-0 model) nearest to ``apex``, apex excluded."""
    verts = np.unique(model.mesh.boundary(wall))
    dist = np.linalg.norm(model.mesh.points[verts] - apex, axis=1)
    order = np.argsort(dist)
    return verts[order[dist[order] > 1e-9][:count]]


def check_nested(first, state, path) -> None:
    """``state`` must refine ``first``'s level-0 mesh: same problem, size and base, vertices kept first."""
    same = ("problem", "mesh_size", "base", "kappa", "volumetric", "isochoric")
    if any(state.params[k] != first.params[k] for k in same):
        raise InputError(f"{path} is not the same problem as the first state ({same})")
    nv0 = first.model.mesh.points.shape[0]
    if not np.array_equal(state.model.mesh.points[:nv0], first.model.mesh.points):
        raise InputError(f"{path} does not refine the first state's mesh")


def level_report(state, tracked: dict) -> dict:
    """The tracked points' deformed z (name -> value) and the diagnostics of one level, printed."""
    model, u = state.model, state.u
    x = model.space.nodes + model.expand(u)
    z = {}
    print(f"level {state.params['refinements']}: {model.n} unknowns, h {model.mesh.h():.3g} mm")
    for wall, apex in APEXES.items():
        z[f"{wall} apex (0)"] = float(node_position(model, u, apex)[2])
        for v in tracked[wall]:
            z[f"{wall}, rho {np.hypot(*model.mesh.points[v, :2]):.2f} mm"] = float(x[v, 2])
    J = np.asarray(det(model.deformation_gradient(jnp.asarray(u))))
    c, q = np.unravel_index(np.argmin(J), J.shape)
    X = model.quad.x[c, q]
    line = (f"  min det F {J.min():.4f} at rho {np.hypot(*X[:2]):.2f}, z {X[2]:.2f} mm (reference), "
            f"{np.linalg.norm(X - APEXES['endocardium']):.2f} mm from the endocardial apex")
    if state.params["problem"] == 3:
        Eff = np.asarray(FibreTension(model, CONTRACTION["tension"]).fibre_strain(jnp.asarray(u)))
        line += f"; E_ff in [{Eff.min():.3f}, {Eff.max():.3f}]"
    print(line, flush=True)
    return z


def print_sequences(levels: list, rows: list) -> None:
    """Per tracked point: z on each level, the changes between levels, the ratio of the last two."""
    print("\n| material point (distance from the axis) | " + " | ".join(f"level {l}" for l in levels)
          + " | " + " | ".join(f"diff {a}->{b}" for a, b in zip(levels, levels[1:])) + " | ratio |")
    print("|---" * (2 * len(levels) + 1) + "|")
    for name in rows[0]:
        z = np.array([r[name] for r in rows])
        d = np.diff(z)
        ratio = f"{d[-2] / d[-1]:.2g}" if d.size >= 2 and d[-1] != 0 else ""
        print(f"| {name} | " + " | ".join(f"{v:.5f}" for v in z) + " | "
              + " | ".join(f"{v:+.4f}" for v in d) + f" | {ratio} |")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("states", nargs="+", help="save_state files of one nested sequence, coarsest first")
    ap.add_argument("--ring", type=int, default=4, help="level-0 wall vertices tracked near each apex")
    args = ap.parse_args()
    try:
        first = load_state(args.states[0])
        tracked = {wall: nearest_wall_vertices(first.model, wall, apex, args.ring) for wall, apex in APEXES.items()}
        levels, rows = [], []
        for path in args.states:
            state = first if path == args.states[0] else load_state(path)
            check_nested(first, state, path)
            levels.append(state.params["refinements"])
            rows.append(level_report(state, tracked))
            del state
            gc.collect()  # one fine level's model at a time
    except InputError as err:
        raise SystemExit(f"probe_apex_points: {err}") from None
    print_sequences(levels, rows)


if __name__ == "__main__":
    main()
