"""hyperoc beside fenicsx-pulse 0.12 on the cardiac elastodynamics benchmark, step 1, on the reference mesh.

The peer: fenicsx-pulse (H. Finsberg, https://github.com/finsberg/fenicsx-pulse, PyPI ``fenicsx-pulse``, MIT licence)
solves the monoventricular benchmark of Arostica et al. (2025) in its demo
``demo/time_dependent/time_dependent_bestel_lv.py``: Holzapfel-Ogden with viscosity (eta/2) tr(Edot^2),
compressibility (kappa/4)(J^2 - 1 - 2 ln J), Robin epicardium (normal, alpha 1e8 Pa/m, beta 5e3 Pa s/m) and base (full
vector, alpha 1e5 Pa/m, beta 5e3 Pa s/m; the demo's base acts along the normal only, this script's on the full vector,
its normal and tangential parts, all on the reference normal as the benchmark states), endocardial follower pressure
and active tension along the fibres from the Bestel ODEs (package ``circulation``), density 1000 kg/m^3,
generalized-alpha (alpha_m 0.2, alpha_f 0.4), dt = 1 ms. This script runs the same model, with fenicsx-pulse's own
parameters, on the benchmark's reference mesh shipped with hyperoc
(`hyperoc.cardiac.benchmark_geometry.reference_mesh`, facet tags 1 endocardium, 2 epicardium, 3 base) and hyperoc's
analytic benchmark fibres (`benchmark_fibres`: the fibre and sheet vectors at the vertices, as P1 vector fields,
orthonormalised at the quadrature points as hyperoc does; the demo's fibres live on the same quadrature space).
fenicsx-pulse's demo takes its fibres from ``cardiac-geometriesx``
(``cardiac_geometries.fibers.lv_ellipsoid.compute_system``), whose frame is `benchmark_frames`' term for term (the
same e_mu, e_theta, f = sin(alpha) e_mu + cos(alpha) e_theta, s = f x (e_mu x e_theta), alpha linear in a Laplace
transmural coordinate) evaluated at quadrature points, but the demo passes helix angles +60 (endocardium) and -60
(epicardium), the opposite of `HELIX` = (-60, 60): its fibres are hyperoc's mirrored, so its twist has the opposite
sense; this script uses hyperoc's. Displacement P1 or P2, and records per step the Newton iterations, wall time, the
displacements of p0 and p1 and the cavity volume (fenicsx-pulse's ``volume_form`` over the endocardium).

Environment (fenicsx-pulse runs in its own venv; hyperoc's python prepares the mesh and fibres)::

    python3.12 -m venv VENV
    VENV/bin/pip install dolfinx-solver-real scipy
    VENV/bin/pip install --no-deps "fenicsx-pulse==0.12.*" circulation pint flexcache flexparser platformdirs \\
        typing_extensions packaging rich rich-argparse markdown-it-py mdurl pygments
    VENV/bin/pip install --no-deps scifem      # or the stand-in below
    LD_LIBRARY_PATH=VENV/lib VENV/bin/python -c "import pulse, circulation.bestel"

``--setup VENV`` runs these commands. The DOLFINx wheel links the MPI library it installs in ``VENV/lib``, hence
``LD_LIBRARY_PATH``. ``scifem`` is published as source only, and its C++ extension builds against DOLFINx's C++
headers and CMake configuration, which the binary wheel does not ship ("Could not find a package configuration file
provided by DOLFINX"). fenicsx-pulse 0.12 imports it at import time but calls it only for cavity and rigid-body
multipliers, unloading and DOLFINx < 0.10, none of which this problem uses. Where it does not build, ``--setup``
writes `SCIFEM_STAND_IN` in its place, a module whose every attribute raises: a call into scifem would end the run.

Usage (the venv made first by ``--setup /tmp/venv-pulse``)::

    python bench/bench_fenicsx_pulse.py --venv /tmp/venv-pulse --degrees 1 2 --steps 1000 50 --ranks 2

For each degree the fenicsx-pulse worker runs, then hyperoc's ``hyperoc benchmark cardiac-elastodynamics --step 1``
on the same mesh and steps, each in a fresh process, one after the other: the first table holds both and the ratios
of wall time and peak memory (hyperoc's over fenicsx-pulse's). Writes ``bench/results/bench_fenicsx_pulse.json``
(`bench/results.py`) after every fenicsx-pulse step, so that a cut run leaves the steps it finished; the load
average at the start and at the end of each fenicsx-pulse run goes into the notes.
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
)
# fenicsx-pulse 0.12 imports scifem at import time (pulse.problem, pulse.utils, pulse.unloading) but calls it only
# for cavity and rigid-body multipliers, unloading and DOLFINx < 0.10: not on this problem's path. Any use raises.
SCIFEM_STAND_IN = (
    '"""Stand-in for scifem, whose C++ extension does not build against the DOLFINx wheel."""\n\n\n'
    "def __getattr__(name):\n"
    '    raise ImportError(f"scifem.{name}: scifem is a stand-in here (its C++ extension needs DOLFINx\'s C++ '
    'development files)")\n')
COLUMNS = ["step", "t (s)", "Newton iterations", "step wall (s)", "p0 ux (m)", "p0 uy (m)", "p0 uz (m)",
           "p1 ux (m)", "p1 uy (m)", "p1 uz (m)", "cavity volume (m^3)"]


def venv_env(venv: Path) -> dict:
    """The environment in which the venv's DOLFINx finds the MPI library that its wheel installed."""
    env = dict(os.environ)
    env["LD_LIBRARY_PATH"] = os.pathsep.join(filter(None, [str(venv / "lib"), env.get("LD_LIBRARY_PATH")]))
    return env


def setup(venv: Path, python: str) -> None:
    """Create the venv with ``python`` (3.12) and install the recipe of the module docstring; exit 1 at the first
    failing command. Where scifem does not build, `SCIFEM_STAND_IN` takes its place."""
    commands = [[python, "-m", "venv", str(venv)]]
    commands += [[str(venv / "bin" / "pip"), "install", *packages] for packages in PIP_STEPS]
    for command in commands:
        _run_setup_step(command, venv)
    if not _run_setup_step([str(venv / "bin" / "pip"), "install", "--no-deps", "scifem"], venv, required=False):
        purelib = "import sysconfig; print(sysconfig.get_paths()['purelib'])"
        site = subprocess.run([str(venv / "bin" / "python"), "-c", purelib], capture_output=True, text=True,
                              check=True).stdout.strip()
        (Path(site) / "scifem").mkdir(exist_ok=True)
        (Path(site) / "scifem" / "__init__.py").write_text(SCIFEM_STAND_IN)
        print(f"scifem did not build: its stand-in written to {site}/scifem", flush=True)
    _run_setup_step([str(venv / "bin" / "python"), "-c", "import pulse, circulation.bestel"], venv)


def _run_setup_step(command: list[str], venv: Path, *, required: bool = True) -> bool:
    """Run one set-up command in the venv's environment, echoed; whether it succeeded (a ``required`` one that
    fails ends the set-up)."""
    print("+", " ".join(command), flush=True)
    succeeded = subprocess.run(command, env=venv_env(venv)).returncode == 0
    if required and not succeeded:
        sys.exit(f"setup failed at: {' '.join(command)}")
    return succeeded


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
    """For each degree, the fenicsx-pulse worker in its venv and then hyperoc's benchmark command, each in a
    fresh process on the same mesh and steps; the results file is rewritten after every fenicsx-pulse step and
    after each hyperoc run, with the ratios once both have run."""
    from results import command_line, write_results

    tables, comparison = [], []
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "benchmark.npz"
        benchmark_data(data)
        for degree, steps in zip(args.degrees, args.steps * len(args.degrees) if len(args.steps) == 1 else args.steps):
            pulses = []
            for ranks in args.ranks:
                notes = f"load average (1, 5, 15 min) at start: {load_average()}"
                pulses.append(_pulse_run(args, data, degree, steps, ranks, lambda done: write_results(
                    "bench_fenicsx_pulse", command_line(), _all(comparison, tables + done)), notes))
                tables += pulses[-1]["tables"]
            ours = _hyperoc_run(degree, steps, Path(tmp) / f"hyperoc-p{degree}")
            comparison += [_comparison_row(degree, steps, pulse, ours) for pulse in pulses]
            write_results("bench_fenicsx_pulse", command_line(), _all(comparison, tables))


def _pulse_run(args, data: Path, degree: int, steps: int, ranks: int, on_step, notes: str) -> dict:
    """The fenicsx-pulse worker for ``degree`` and ``steps`` on ``ranks`` MPI ranks, each bound to a core: its
    tables, summary, per-step rows and process wall time."""
    rows, summary = [], None
    launcher = [str(args.venv / "bin" / "mpiexec"), "-n", str(ranks), "-bind-to", "core"] if ranks > 1 else []
    command = [*launcher, str(args.venv / "bin" / "python"), __file__, "--worker", str(data), "--degree", str(degree),
               "--steps", str(steps), "--quadrature", str(args.quadrature)]
    start = time.perf_counter()
    with subprocess.Popen(command, stdout=subprocess.PIPE, text=True, env=venv_env(args.venv)) as proc:
        for line in proc.stdout:
            record = json.loads(line)
            if "step" in record:
                rows.append([record[c] for c in ("step", "t", "iterations", "wall", *_PROBE_KEYS, "volume")])
            else:
                summary = record
            on_step(_tables(degree, ranks, rows, summary, notes + " (running)"))
    if proc.returncode != 0:
        sys.exit(f"the fenicsx-pulse worker (P{degree}, {ranks} ranks) exited with status {proc.returncode}")
    notes = f"{notes}; at end: {load_average()}"
    return {"ranks": ranks, "tables": _tables(degree, ranks, rows, summary, notes), "summary": summary, "rows": rows,
            "wall": time.perf_counter() - start}


def _hyperoc_run(degree: int, steps: int, out: Path) -> dict:
    """hyperoc's benchmark command, step 1, on the reference mesh for ``steps`` steps of DT: its
    ``benchmark.json`` and the process wall time."""
    command = [sys.executable, "-m", "hyperoc.app.cli", "benchmark", "cardiac-elastodynamics", "--step", "1",
               "--degree", str(degree), "--mesh", "reference", "--end-time", f"{steps * DT:g}", "--out", str(out),
               "--no-progress"]
    start = time.perf_counter()
    subprocess.run(command, check=True)
    return {"record": json.loads((out / "benchmark.json").read_text()), "wall": time.perf_counter() - start}


def _comparison_row(degree: int, steps: int, pulse: dict, ours: dict) -> list:
    """hyperoc against fenicsx-pulse: process wall times, Newton iterations per step, peak memory, the peak
    displacements of p0 and p1 (mm; fenicsx-pulse's over its steps, hyperoc's over its 10 ms samples)."""
    record, summary, rows = ours["record"], pulse["summary"], np.asarray(pulse["rows"], dtype=float)
    peak = lambda u: 1e3 * float(np.max(np.linalg.norm(np.asarray(u, dtype=float), axis=1)))  # noqa: E731
    return [degree, steps, record["unknowns"], pulse["ranks"], ours["wall"], pulse["wall"],
            ours["wall"] / pulse["wall"],
            record["newton_iterations"]["mean"], float(np.mean(rows[:, 2])),
            record["peak_memory_mib"], summary["peak_rss_mb"], record["peak_memory_mib"] / summary["peak_rss_mb"],
            peak(record["p0"]), peak(rows[:, 4:7]), peak(record["p1"]), peak(rows[:, 7:10])]


COMPARISON = ["degree", "steps", "unknowns", "fenicsx-pulse MPI ranks", "hyperoc wall (s)", "fenicsx-pulse wall (s)",
              "wall ratio",
              "hyperoc Newton iterations per step", "fenicsx-pulse Newton iterations per step",
              "hyperoc peak memory (MiB)", "fenicsx-pulse peak RSS, all ranks (MiB)", "memory ratio",
              "hyperoc peak |p0| (mm)", "fenicsx-pulse peak |p0| (mm)",
              "hyperoc peak |p1| (mm)", "fenicsx-pulse peak |p1| (mm)"]


def _all(comparison: list, tables: list) -> list:
    """The comparison table (when a degree has both runs) before the fenicsx-pulse tables."""
    from results import table

    if not comparison:
        return tables
    return [table("hyperoc and fenicsx-pulse 0.12 side by side: benchmark step 1 on the reference mesh, dt = 1 ms",
                  COMPARISON, comparison, COMPARISON_NOTES)] + tables


COMPARISON_NOTES = (
    "Each run is a fresh process on the same 2 cores, one after the other in one invocation: hyperoc's "
    "`hyperoc benchmark cardiac-elastodynamics --step 1` (JAX compilation, checkpoints every 50 steps, outputs) and "
    "the fenicsx-pulse worker (FFCx compilation, DynamicProblem with its default Newton and MUMPS LU) on 1 or more "
    "MPI ranks, each bound to a core (mpiexec -bind-to core); wall ratio and "
    "memory ratio are hyperoc's over fenicsx-pulse's. The problems differ where the packages do: hyperoc steps "
    "its theta scheme and writes I1 isochoric with the fibre invariants of the full C, fenicsx-pulse "
    "steps generalized-alpha and applies the isochoric split to the whole passive energy; its Newton stops at its "
    "own tolerances.")
DT = 1e-3  # the benchmark's time step (s), fenicsx-pulse's default


_PROBE_KEYS = ("p0x", "p0y", "p0z", "p1x", "p1y", "p1z")


def _tables(degree: int, ranks: int, rows: list, summary: dict | None, notes: str) -> list[dict]:
    """The summary table (set-up, steps, per-step wall time, Newton iterations, peak RSS) and the per-step table
    sampled every `SAMPLE_EVERY` steps (the codes' 10 ms)."""
    from results import table

    tables = []
    if summary is not None:
        steps = [r[3] for r in rows]
        tables.append(table(
            f"fenicsx-pulse 0.12, step 1, P{degree}, {ranks} MPI rank(s): cost",
            ["degree", "dofs", "set-up wall (s)", "steps", "stepping wall (s)", "per step mean (s)",
             "Newton iterations per step (mean)", "peak RSS, all ranks (MiB)"],
            [[degree, summary["dofs"], summary["setup"], len(rows), float(np.sum(steps)), float(np.mean(steps)),
              float(np.mean([r[2] for r in rows])), summary["peak_rss_mb"]]], notes))
    sampled = [r for r in rows if r[0] % SAMPLE_EVERY == 0 or r is rows[-1]]
    tables.append(table(f"fenicsx-pulse 0.12, step 1, P{degree}, {ranks} MPI rank(s): every {SAMPLE_EVERY} steps",
                        COLUMNS, sampled, notes))
    return tables


SAMPLE_EVERY = 10


def worker(data: Path, degree: int, steps: int, quadrature: int) -> None:
    """In the fenicsx-pulse venv, on each MPI rank: build the benchmark problem on the given mesh and fibres and
    step it; rank 0 prints one JSON line per step and one summary line (set-up wall time, dofs, peak RSS summed
    over the ranks)."""
    import resource

    from mpi4py import MPI

    comm = MPI.COMM_WORLD
    start = time.perf_counter()
    mesh, facet_tags, f0, s0, probes = _dolfinx_benchmark(np.load(data))
    f0, s0 = _quadrature_frame(mesh, f0, s0, quadrature)
    problem, traction, activation, volume = _pulse_problem(mesh, facet_tags, f0, s0, degree, quadrature)
    pressures, tensions = _bestel(steps, problem.parameters["dt"].to_base_units())
    probe = _probe(mesh, probes)
    dofs = problem.u.function_space.dofmap.index_map.size_global * 3
    setup_wall = comm.allreduce(time.perf_counter() - start, op=MPI.MAX)
    dt = problem.parameters["dt"].to_base_units()
    for i in range(steps):
        traction.assign(pressures[i])
        activation.assign(tensions[i])
        comm.Barrier()
        tic = time.perf_counter()
        problem.solve()
        wall = comm.allreduce(time.perf_counter() - tic, op=MPI.MAX)
        record = {"step": i + 1, "t": (i + 1) * dt, "iterations": problem.problem.solver.getIterationNumber(),
                  "wall": wall, **dict(zip(_PROBE_KEYS, probe(problem.u))), "volume": volume()}
        if comm.rank == 0:
            print(json.dumps(record), flush=True)
    peak = comm.allreduce(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
    if comm.rank == 0:
        print(json.dumps({"setup": setup_wall, "dofs": dofs, "peak_rss_mb": peak, "ranks": comm.size}), flush=True)


def _dolfinx_benchmark(data):
    """DOLFINx mesh, facet tags, P1 fibre and sheet fields and probe points from `benchmark_data`'s arrays."""
    import basix.ufl
    import dolfinx
    import ufl
    from mpi4py import MPI

    domain = ufl.Mesh(basix.ufl.element("Lagrange", "tetrahedron", 1, shape=(3,)))
    root = MPI.COMM_WORLD.rank == 0  # rank 0 holds the mesh; create_mesh partitions it
    cells, points = data["cells"].astype(np.int64), data["points"]
    facets, tags = data["facets"].astype(np.int64), data["tags"].astype(np.int32)
    if not root:
        cells, points, facets, tags = cells[:0], points[:0], facets[:0], tags[:0]
    mesh = dolfinx.mesh.create_mesh(MPI.COMM_WORLD, cells, domain, points)
    entities, values = dolfinx.io.distribute_entity_data(mesh, 2, facets, tags)
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


def _quadrature_frame(mesh, f, s, degree: int):
    """The fibre and sheet fields at the quadrature points of ``degree`` (the space of the demo's fibres,
    ``Quadrature_6``): the P1 interpolants ``f``, ``s`` orthonormalised point by point, as hyperoc's
    `FieldFrames` does. The raw interpolant of unit vertex vectors that turn through the wall is shorter than
    1 between the vertices, which would scale the fibre stiffness and the active stress down."""
    import basix.ufl
    import dolfinx
    import ufl

    element = basix.ufl.quadrature_element(mesh.basix_cell(), value_shape=(3,), degree=degree)
    space = dolfinx.fem.functionspace(mesh, element)
    fibre = f / ufl.sqrt(ufl.inner(f, f))
    sheet = s - ufl.inner(s, fibre) * fibre
    fields = []
    for expression in (fibre, sheet / ufl.sqrt(ufl.inner(sheet, sheet))):
        field = dolfinx.fem.Function(space)
        field.interpolate(dolfinx.fem.Expression(expression, space.element.interpolation_points))
        fields.append(field)
    return fields


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
    # The benchmark's springs and dashpots act on the reference normal N: along N on the epicardium, the full
    # vector on the base. A RobinBC acts along N or, perpendicular, in the tangent plane: the base takes both.
    robin = []
    for name, alpha, parts in (("EPI", 1e8, (False,)), ("BASE", 1e5, (False, True))):
        for perpendicular in parts:
            for value, damping in ((constant(alpha, "Pa / m"), False), (constant(5e3, "Pa s/ m"), True)):
                robin.append(pulse.RobinBC(value=value, marker=markers[name][0], damping=damping,
                                           perpendicular=perpendicular, normal="reference"))
    bcs = pulse.BoundaryConditions(robin=tuple(robin),
                                   neumann=(pulse.NeumannBC(traction=pressure, marker=markers["ENDO"][0]),))
    problem = pulse.problem.DynamicProblem(
        model=model, geometry=geometry, bcs=bcs,
        # A step whose Newton iteration fails ends the run (fenicsx-pulse's default would go on from it).
        parameters={"base_bc": pulse.problem.BaseBC.free, "u_space": f"P_{degree}", "raise_on_failure": True})
    form = dolfinx.fem.form(geometry.volume_form(u=problem.u, marker="ENDO") * geometry.ds(markers["ENDO"][0]))
    comm = mesh.comm
    return problem, pressure, tension, lambda: comm.allreduce(float(dolfinx.fem.assemble_scalar(form)))


def _bestel(steps: int, dt: float):
    """Endocardial pressure and active tension (Pa) at t = dt, ..., steps dt from the Bestel ODEs of
    ``circulation.bestel`` with its default (the benchmark's) parameters."""
    import circulation.bestel
    from scipy.integrate import solve_ivp

    times = dt * np.arange(0, steps + 1)
    solve = [solve_ivp(m, [0.0, times[-1]], [0.0], t_eval=times, method="Radau").y[0][1:]
             for m in (circulation.bestel.BestelPressure(), circulation.bestel.BestelActivation())]
    return solve[0], solve[1]


def _probe(mesh, points):
    """A function of a displacement giving its values at ``points`` (n, 3) as a flat list on every rank, each
    point evaluated on the lowest rank that owns a cell holding it."""
    import dolfinx
    from mpi4py import MPI

    comm, owned = mesh.comm, mesh.topology.index_map(mesh.topology.dim).size_local
    tree = dolfinx.geometry.bb_tree(mesh, mesh.topology.dim)
    colliding = dolfinx.geometry.compute_colliding_cells(
        mesh, dolfinx.geometry.compute_collisions_points(tree, points), points)
    cells = np.array([next((c for c in colliding.links(k) if c < owned), -1) for k in range(len(points))],
                     dtype=np.int32)
    owner = np.where(cells >= 0, comm.rank, comm.size)
    comm.Allreduce(MPI.IN_PLACE, owner, op=MPI.MIN)
    mine = owner == comm.rank

    def values(u) -> list:
        here = np.zeros((len(points), 3))
        if mine.any():
            here[mine] = u.eval(points[mine], cells[mine])
        comm.Allreduce(MPI.IN_PLACE, here, op=MPI.SUM)
        return here.ravel().tolist()

    return values


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--setup", type=Path, metavar="VENV", help="create VENV with the recipe above and stop")
    ap.add_argument("--python", default="python3.12", help="the Python 3.12 that --setup builds the venv from")
    ap.add_argument("--venv", type=Path, default=Path("/tmp/venv-pulse"), help="the fenicsx-pulse venv")
    ap.add_argument("--degrees", type=int, nargs="+", default=[1, 2], choices=[1, 2])
    ap.add_argument("--steps", type=int, nargs="+", default=[1000],
                    help="time steps of 1 ms (1,000: the whole 1 s), one for all degrees or one per degree")
    ap.add_argument("--ranks", type=int, nargs="+", default=[1, 2],
                    help="fenicsx-pulse's MPI ranks, a run for each (hyperoc runs once per degree, on all cores)")
    ap.add_argument("--quadrature", type=int, default=6, help="quadrature degree (the demo's 6)")
    ap.add_argument("--worker", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--degree", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if len(args.steps) not in (1, len(args.degrees)):
        ap.error("--steps takes one count for all degrees or one per degree")
    if args.setup:
        setup(args.setup, args.python)
    elif args.worker:
        worker(args.worker, args.degree, args.steps[0], args.quadrature)
    else:
        sys.path.insert(0, str(HERE))
        run(args)


if __name__ == "__main__":
    main()
