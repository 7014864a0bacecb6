"""fenicsx-pulse 0.12 on the cardiac elastodynamics benchmark, step 1, on hyperoc's reference mesh.

The peer for issue 49's wall-time comparison: fenicsx-pulse (H. Finsberg, https://github.com/finsberg/fenicsx-pulse,
PyPI ``fenicsx-pulse``, MIT licence) solves the monoventricular benchmark of Arostica et al. (2025) in its demo
``demo/time_dependent/time_dependent_bestel_lv.py``: Holzapfel-Ogden with viscosity (eta/2) tr(Edot^2),
compressibility (kappa/4)(J^2 - 1 - 2 ln J), Robin epicardium (normal, alpha 1e8 Pa/m, beta 5e3 Pa s/m) and base
(full vector, alpha 1e5 Pa/m, beta 5e3 Pa s/m), endocardial follower pressure and active tension along the fibres
from the Bestel ODEs (package ``circulation``), density 1000 kg/m^3, generalized-alpha (alpha_m 0.2, alpha_f 0.4),
dt = 1 ms. This script runs the same model, with fenicsx-pulse's own parameters, on the benchmark's reference
mesh shipped with hyperoc (`hyperoc.cardiac.benchmark_geometry.reference_mesh`, facet tags 1 endocardium,
2 epicardium, 3 base) and hyperoc's analytic benchmark fibres (`benchmark_fibres`: the fibre and sheet vectors at
the vertices, as P1 vector fields). fenicsx-pulse's demo takes its fibres from ``cardiac-geometriesx``
(``cardiac_geometries.fibers.lv_ellipsoid.compute_system``), whose frame is `benchmark_frames`' term for term (the
same e_mu, e_theta, f = sin(alpha) e_mu + cos(alpha) e_theta, s = f x (e_mu x e_theta), alpha linear in a Laplace
transmural coordinate) evaluated at quadrature points, but the demo passes helix angles +60 (endocardium) and -60
(epicardium), the opposite of `HELIX` = (-60, 60): its fibres are hyperoc's mirrored, so its twist has the
opposite sense; this script uses hyperoc's. Displacement P1 or P2, and records per step the Newton iterations,
wall time, the displacements of p0 and p1 and the cavity volume (fenicsx-pulse's ``volume_form`` over the endocardium).

Environment (fenicsx-pulse runs in its own venv; hyperoc's python prepares the mesh and fibres)::

    python3.12 -m venv VENV
    VENV/bin/pip install dolfinx-solver-real scipy
    VENV/bin/pip install --no-deps "fenicsx-pulse==0.12.*" circulation pint flexcache flexparser platformdirs \\
        typing_extensions packaging rich rich-argparse markdown-it-py mdurl pygments
    VENV/bin/pip install --no-deps scifem
    LD_LIBRARY_PATH=VENV/lib VENV/bin/python -c "import pulse, circulation.bestel"

``--setup VENV`` runs these commands. The DOLFINx wheel links the MPI library it installs in ``VENV/lib``, hence
``LD_LIBRARY_PATH``. fenicsx-pulse imports ``scifem`` at import time (``pulse.problem``, ``pulse.utils``) although
this problem (no cavity or rigid-body multiplier) solves with DOLFINx's own SNES problem; ``scifem`` is published as
source only and its C++ extension builds against DOLFINx's C++ headers and CMake configuration, which the binary
wheel does not ship: with PyPI alone the last two commands fail (``scifem``: "Could not find a package
configuration file provided by DOLFINX"), and ``--setup`` stops there. With a DOLFINx that ships its development
files (a source build), ``pip install --no-deps scifem`` completes the environment.

Usage (the venv made first by ``--setup /tmp/venv-pulse``)::

    python bench/bench_fenicsx_pulse.py --venv /tmp/venv-pulse --degrees 1 2 --steps 20

Writes ``bench/results/bench_fenicsx_pulse.json`` (`bench/results.py`) after every step, so that a cut run
leaves the steps it finished; the load average at the start and at the end of each run goes into the notes.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
PIP_STEPS = (
    ["dolfinx-solver-real", "scipy"],
    ["--no-deps", "fenicsx-pulse==0.12.*", "circulation", "pint", "flexcache", "flexparser", "platformdirs",
     "typing_extensions", "packaging", "rich", "rich-argparse", "markdown-it-py", "mdurl", "pygments"],
    ["--no-deps", "scifem"],
)
COLUMNS = ["step", "t (s)", "Newton iterations", "step wall (s)", "p0 ux (m)", "p0 uy (m)", "p0 uz (m)",
           "p1 ux (m)", "p1 uy (m)", "p1 uz (m)", "cavity volume (m^3)"]


def venv_env(venv: Path) -> dict:
    """The environment in which the venv's DOLFINx finds the MPI library that its wheel installed."""
    env = dict(os.environ)
    env["LD_LIBRARY_PATH"] = os.pathsep.join(filter(None, [str(venv / "lib"), env.get("LD_LIBRARY_PATH")]))
    return env


def setup(venv: Path, python: str) -> None:
    """Create the venv with ``python`` (3.12) and install the recipe of the module docstring; exit 1 at the first
    failing command."""
    commands = [[python, "-m", "venv", str(venv)]]
    commands += [[str(venv / "bin" / "pip"), "install", *packages] for packages in PIP_STEPS]
    commands += [[str(venv / "bin" / "python"), "-c", "import pulse, circulation.bestel"]]
    for command in commands:
        print("+", " ".join(command), flush=True)
        if subprocess.run(command, env=venv_env(venv)).returncode != 0:
            sys.exit(f"setup failed at: {' '.join(command)} (see the module docstring on scifem)")


def benchmark_data(path: Path) -> None:
    """Write the reference mesh (points, cells, tagged boundary facets) and hyperoc's benchmark fibres at its
    vertices to ``path`` (.npz), for the worker in the fenicsx-pulse venv."""
    from hyperoc.cardiac import benchmark_geometry as bg

    mesh = bg.reference_mesh()
    frames = bg.benchmark_fibres(mesh)
    facets = [mesh.boundary(name) for name in bg.TAGS]
    tags = np.concatenate([np.full(len(f), tag) for f, tag in zip(facets, bg.TAGS.values())])
    np.savez(path, points=mesh.points, cells=mesh.cells, facets=np.concatenate(facets), tags=tags,
             fibres=frames.fibres, sheets=frames.sheets, probes=np.array([bg.P0, bg.P1]))


def load_average() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def run(args) -> None:
    """Run the worker in the venv for each degree, rewriting the results file after every step."""
    from results import command_line, write_results

    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "benchmark.npz"
        benchmark_data(data)
        tables = []
        for degree in args.degrees:
            notes = f"load average (1, 5, 15 min) at start: {load_average()}"
            rows, summary = [], None
            command = [str(args.venv / "bin" / "python"), __file__, "--worker", str(data), "--degree", str(degree),
                       "--steps", str(args.steps), "--quadrature", str(args.quadrature)]
            with subprocess.Popen(command, stdout=subprocess.PIPE, text=True, env=venv_env(args.venv)) as proc:
                for line in proc.stdout:
                    record = json.loads(line)
                    if "step" in record:
                        rows.append([record[c] for c in ("step", "t", "iterations", "wall", *_PROBE_KEYS, "volume")])
                    else:
                        summary = record
                    done = tables + _tables(degree, rows, summary, notes + " (running)")
                    write_results("bench_fenicsx_pulse", command_line(), done)
            if proc.returncode != 0:
                sys.exit(f"the fenicsx-pulse worker (P{degree}) exited with status {proc.returncode}")
            tables += _tables(degree, rows, summary, f"{notes}; at end: {load_average()}")
            write_results("bench_fenicsx_pulse", command_line(), tables)


_PROBE_KEYS = ("p0x", "p0y", "p0z", "p1x", "p1y", "p1z")


def _tables(degree: int, rows: list, summary: dict | None, notes: str) -> list[dict]:
    """The summary table (set-up, steps, per-step wall time, Newton iterations, peak RSS) and the per-step table."""
    from results import table

    tables = []
    if summary is not None:
        steps = [r[3] for r in rows]
        tables.append(table(
            f"fenicsx-pulse 0.12, step 1, P{degree}: cost",
            ["degree", "dofs", "set-up wall (s)", "steps", "stepping wall (s)", "per step mean (s)",
             "Newton iterations per step (mean)", "peak RSS (MB)"],
            [[degree, summary["dofs"], summary["setup"], len(rows), float(np.sum(steps)), float(np.mean(steps)),
              float(np.mean([r[2] for r in rows])), summary["peak_rss_mb"]]], notes))
    tables.append(table(f"fenicsx-pulse 0.12, step 1, P{degree}: per step", COLUMNS, rows, notes))
    return tables


def worker(data: Path, degree: int, steps: int, quadrature: int) -> None:
    """In the fenicsx-pulse venv: build the benchmark problem on the given mesh and fibres and step it, printing
    one JSON line per step and one summary line (set-up wall time, dofs, peak RSS)."""
    import resource

    start = time.perf_counter()
    mesh, facet_tags, f0, s0, probes = _dolfinx_benchmark(np.load(data))
    problem, traction, activation, volume = _pulse_problem(mesh, facet_tags, f0, s0, degree, quadrature)
    pressures, tensions = _bestel(steps, problem.parameters["dt"].to_base_units())
    locate = _point_locator(mesh, probes)
    dofs = problem.u.function_space.dofmap.index_map.size_global * 3
    setup_wall = time.perf_counter() - start
    dt = problem.parameters["dt"].to_base_units()
    for i in range(steps):
        traction.assign(pressures[i])
        activation.assign(tensions[i])
        tic = time.perf_counter()
        problem.solve()
        wall = time.perf_counter() - tic
        u = problem.u.eval(*locate).ravel()
        record = {"step": i + 1, "t": (i + 1) * dt, "iterations": problem.problem.solver.getIterationNumber(),
                  "wall": wall, **dict(zip(_PROBE_KEYS, u.tolist())), "volume": volume()}
        print(json.dumps(record), flush=True)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps({"setup": setup_wall, "dofs": dofs, "peak_rss_mb": peak}), flush=True)


def _dolfinx_benchmark(data):
    """DOLFINx mesh, facet tags, P1 fibre and sheet fields and probe points from `benchmark_data`'s arrays."""
    import basix.ufl
    import dolfinx
    import ufl
    from mpi4py import MPI

    domain = ufl.Mesh(basix.ufl.element("Lagrange", "tetrahedron", 1, shape=(3,)))
    mesh = dolfinx.mesh.create_mesh(MPI.COMM_WORLD, data["cells"].astype(np.int64), domain, data["points"])
    entities, values = dolfinx.io.distribute_entity_data(mesh, 2, data["facets"].astype(np.int64),
                                                         data["tags"].astype(np.int32))
    mesh.topology.create_connectivity(2, 3)
    facet_tags = dolfinx.mesh.meshtags_from_entities(mesh, 2, dolfinx.graph.adjacencylist(entities), values)
    vertex = {tuple(p): k for k, p in enumerate(np.round(data["points"], 12))}
    space = dolfinx.fem.functionspace(mesh, ("Lagrange", 1, (3,)))
    fields = []
    for name in ("fibres", "sheets"):
        field = dolfinx.fem.Function(space, name=name)
        field.interpolate(lambda x, a=data[name]: a[[vertex[tuple(p)] for p in np.round(x.T, 12)]].T)
        fields.append(field)
    return mesh, facet_tags, fields[0], fields[1], data["probes"]


def _pulse_problem(mesh, facet_tags, f0, s0, degree: int, quadrature: int):
    """fenicsx-pulse's DynamicProblem of the demo (its material, viscosity, compressibility, Robin and
    Neumann conditions, free base) on the given mesh; returns the problem, the pressure and tension
    constants to assign per step, and a function giving the cavity volume (m^3) at the current state."""
    import dolfinx
    import pulse

    markers = {"ENDO": (1, 2), "EPI": (2, 2), "BASE": (3, 2)}
    geometry = pulse.HeartGeometry(mesh=mesh, facet_tags=facet_tags, markers=markers,
                                   metadata={"quadrature_degree": quadrature})

    def constant(value, unit):
        return pulse.Variable(dolfinx.fem.Constant(mesh, dolfinx.default_scalar_type(value)), unit)

    tension, pressure = constant(0.0, "Pa"), constant(0.0, "Pa")
    model = pulse.CardiacModel(
        material=pulse.HolzapfelOgden(f0=f0, s0=s0, **pulse.HolzapfelOgden.orthotropic_parameters()),
        active=pulse.ActiveStress(f0, activation=tension),
        compressibility=pulse.compressibility.Compressible2(),
        viscoelasticity=pulse.viscoelasticity.Viscous())
    robin = []
    for name, alpha in (("EPI", 1e8), ("BASE", 1e5)):
        robin.append(pulse.RobinBC(value=constant(alpha, "Pa / m"), marker=markers[name][0]))
        robin.append(pulse.RobinBC(value=constant(5e3, "Pa s/ m"), marker=markers[name][0], damping=True))
    bcs = pulse.BoundaryConditions(robin=tuple(robin),
                                   neumann=(pulse.NeumannBC(traction=pressure, marker=markers["ENDO"][0]),))
    problem = pulse.problem.DynamicProblem(
        model=model, geometry=geometry, bcs=bcs,
        # A step whose Newton iteration fails ends the run (fenicsx-pulse's default would go on from it).
        parameters={"base_bc": pulse.problem.BaseBC.free, "u_space": f"P_{degree}", "raise_on_failure": True})
    form = dolfinx.fem.form(geometry.volume_form(u=problem.u) * geometry.ds(markers["ENDO"][0]))
    return problem, pressure, tension, lambda: float(dolfinx.fem.assemble_scalar(form))


def _bestel(steps: int, dt: float):
    """Endocardial pressure and active tension (Pa) at t = dt, ..., steps dt from the Bestel ODEs of
    ``circulation.bestel`` with its default (the benchmark's) parameters."""
    import circulation.bestel
    from scipy.integrate import solve_ivp

    times = dt * np.arange(0, steps + 1)
    solve = [solve_ivp(m, [0.0, times[-1]], [0.0], t_eval=times, method="Radau").y[0][1:]
             for m in (circulation.bestel.BestelPressure(), circulation.bestel.BestelActivation())]
    return solve[0], solve[1]


def _point_locator(mesh, points):
    """(points, cells) for ``Function.eval`` at the given points (n, 3)."""
    import dolfinx

    tree = dolfinx.geometry.bb_tree(mesh, mesh.topology.dim)
    colliding = dolfinx.geometry.compute_colliding_cells(
        mesh, dolfinx.geometry.compute_collisions_points(tree, points), points)
    return points, np.array([colliding.links(k)[0] for k in range(len(points))], dtype=np.int32)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--setup", type=Path, metavar="VENV", help="create VENV with the recipe above and stop")
    ap.add_argument("--python", default="python3.12", help="the Python 3.12 that --setup builds the venv from")
    ap.add_argument("--venv", type=Path, default=Path("/tmp/venv-pulse"), help="the fenicsx-pulse venv")
    ap.add_argument("--degrees", type=int, nargs="+", default=[1, 2], choices=[1, 2])
    ap.add_argument("--steps", type=int, default=1000, help="time steps of 1 ms (1,000: the whole 1 s)")
    ap.add_argument("--quadrature", type=int, default=6, help="quadrature degree (the demo's 6)")
    ap.add_argument("--worker", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--degree", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.setup:
        setup(args.setup, args.python)
    elif args.worker:
        worker(args.worker, args.degree, args.steps, args.quadrature)
    else:
        sys.path.insert(0, str(HERE))
        run(args)


if __name__ == "__main__":
    main()
