"""Land et al. (2015) problem 2 solved by DOLFINx (UFL forms, FFCx kernels, PETSc) against hyperoc's
JAX kernels (serial, and distributed on MPI + PETSc), the same discrete problem in one run.

The problem is `hyperoc.app.distributed_statics`'s ``ventricle``: the idealized LV of
`hyperoc.cardiac.land.ventricle_problem` (h = 6 mm, ``--refinements`` uniform refinements; 0: 1,706
unknowns, 1: 11,569), Taylor-Hood P2-P1, incompressible (``L = int W(Ebar) + p (J - 1) dX``,
`hyperoc.mechanics.mixed.TaylorHoodModel`), isotropic Guccione on the isochoric strain ``Ebar`` (C = 10
kPa, bf = bt = bfs = 1), base clamped, endocardial pressure 10 kPa on the deformed endocardium (the
follower load ``-p J F^-T N dA`` of `hyperoc.mechanics.follower`), 20 load steps, full Newton steps,
each stopped when ``|du|_inf <= 1e-11 |u + du|_inf + 1e-15`` on the displacements and on the pressures
apart. The DOLFINx solve is built from hyperoc's mesh (made by Gmsh on rank 0): its vertices and the P2
nodes of its curved cells become a distributed DOLFINx mesh with a P2 coordinate element, the base and
endocardium facets its facet tags; the energy is written in UFL and differentiated by UFL; the cell
integrals use hyperoc's quadrature rule for P2 cells (`hyperoc.fem.quadrature.simplex_rule` of degree 4, as
an FFCx custom rule), the facet integrals a rule of degree 4 (the follower integrand ``v . cof(F) N dA`` is
a polynomial of degree 4 on the curved facets: exact for both); the Newton loop (own, in this file)
factors the tangent with MUMPS (PC lu) at every iteration.

Each row is one process tree: hyperoc's serial path (``python -m hyperoc.app.distributed_statics --serial``,
`hyperoc.dynamics.statics.solve_static` with its sparse LU), hyperoc's distributed path on 1 and 2 ranks,
and the DOLFINx solve on 1 and 2 ranks (``mpiexec -n k python bench/bench_dolfinx.py --worker dolfinx``).
Run it with the ``mpi`` environment's python (docs/distributed.md), which also holds DOLFINx
(the ``dolfinx-solver-real`` wheel) and mpiexec, from the repository root:

    venv-mpi/bin/python bench/bench_dolfinx.py --refinements 0

    venv-mpi/bin/python bench/bench_dolfinx.py --refinements 0,1

Reported per row: unknowns (free displacement dofs and vertex pressures), ranks, the wall time of the
set-up (mesh, spaces, forms with their compilation for DOLFINx; mesh and model for hyperoc) and of the
solve (hyperoc's JAX compilation included), Newton iterations (all load steps), seconds per Newton
iteration, the split of the solve into residual and tangent evaluation (JAX kernels and assembly;
DOLFINx form assembly) and the factorizations and solves (largest over the ranks), the largest peak
resident memory over the ranks, the z of the deformed endocardial apex (0, 0, -17) and epicardial
apex (0, 0, -20), and the differences from the serial path: of the apex positions and of the nodal
displacements relative to the largest one. A second table times one Newton iteration's parts
compiled, at u = 0 and the full load, on the distributed paths (hyperoc's kernels and DOLFINx's
forms, MUMPS for both): the residual + tangent evaluation and assembly against the factorization +
solve, the mean of ``--repeat`` repetitions, and the compilation of the kernels. DOLFINx's forms are
compiled into a fresh cache directory in every run (``--warm-cache`` keeps FFCx's default cache), as
hyperoc's JAX kernels are compiled in every run. Writes ``bench/results/bench_dolfinx.json``
(`bench/results.py`), or ``--results NAME``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: `hyperoc.app.distributed_statics`'s ventricle: mesh size (mm), load steps, halvings allowed, Newton options
MESH_SIZE, STEPS, CUTBACKS, RTOL, ATOL, MAX_ITER = 6.0, 20, 40, 1e-11, 1e-15, 30
#: hyperoc's local order of a P2 tetrahedron's nodes (vertices, then the edges (0,1), (0,2), (0,3), (1,2),
#: (1,3), (2,3)) taken to basix's (vertices, then the edges (2,3), (1,3), (1,2), (0,3), (0,2), (0,1))
TET_P2_TO_BASIX = [0, 1, 2, 3, 9, 8, 7, 6, 5, 4]

COLUMNS = ["level", "unknowns", "path", "ranks", "set-up (s)", "solve (s)", "Newton iterations",
           "s per Newton iteration", "residual + tangent / factor + solves (s)", "peak RSS per rank, max (MB)",
           "z endo apex (mm)", "z epi apex (mm)", "max |z_apex - z_serial| (mm)", "max |u - u_serial| / max |u|"]


# --- the DOLFINx solve (worker, under mpiexec) -------------------------------------------------------

def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _facet_keys(facets: np.ndarray, nv: int) -> np.ndarray:
    """A number per facet (nf, 3) of vertex indices, independent of the vertex order."""
    f = np.sort(np.asarray(facets, dtype=np.int64), axis=1)
    return (f[:, 0] * nv + f[:, 1]) * nv + f[:, 2]


def _hyperoc_mesh(refinements: int):
    """hyperoc's ventricle mesh and its P2 space (nodes: vertices first, then the edge nodes)."""
    from hyperoc.fem.geometry import ventricle
    from hyperoc.fem.spaces import VectorSpace

    mesh = ventricle(MESH_SIZE, curved=True, refinements=refinements)
    return mesh, VectorSpace(mesh, 2)


def _dolfinx_mesh(comm, refinements: int):
    """The DOLFINx mesh (P2 coordinate element) of hyperoc's mesh, built on rank 0 and distributed,
    its facet tags (1 base, 2 endocardium), and on rank 0 hyperoc's mesh and space (else None)."""
    import basix.ufl
    import dolfinx.mesh

    if comm.rank == 0:
        mesh, space = _hyperoc_mesh(refinements)
        cells, x = space.cell_nodes[:, TET_P2_TO_BASIX].astype(np.int64), space.nodes
        nv = mesh.points.shape[0]
        keys = {name: _facet_keys(mesh.boundary(name), nv) for name in ("base", "endocardium")}
    else:
        mesh = space = keys = nv = None
        cells, x = np.zeros((0, 10), np.int64), np.zeros((0, 3))
    nv, keys = comm.bcast((nv, keys), root=0)
    element = basix.ufl.element("Lagrange", "tetrahedron", 2, shape=(3,))
    domain = dolfinx.mesh.create_mesh(comm, cells, element, x)
    # Exterior facets -> their vertices' input node numbers (hyperoc's vertex numbers) -> the named sets.
    tdim = domain.topology.dim
    domain.topology.create_entities(tdim - 1)
    domain.topology.create_connectivity(tdim - 1, tdim)
    exterior = dolfinx.mesh.exterior_facet_indices(domain.topology)
    nodes = dolfinx.mesh.entities_to_geometry(domain, tdim - 1, exterior)[:, :3]
    original = np.asarray(domain.geometry.input_global_indices, dtype=np.int64)[nodes]
    if original.size and original.max() >= nv:
        raise RuntimeError("a facet vertex is not a vertex of hyperoc's mesh: node ordering broken")
    mine = _facet_keys(original, nv) if len(exterior) else np.zeros(0, np.int64)
    marked, values = [], []
    for tag, name in ((1, "base"), (2, "endocardium")):
        hit = np.isin(mine, keys[name])
        marked.append(exterior[hit])
        values.append(np.full(hit.sum(), tag, np.int32))
    found = [comm.allreduce(int(m.size)) for m in marked]
    expected = [keys["base"].size, keys["endocardium"].size]
    if found != expected:
        raise RuntimeError(f"facet tags: found {found} base / endocardium facets, hyperoc has {expected}")
    order = np.argsort(np.concatenate(marked))
    tags = dolfinx.mesh.meshtags(domain, tdim - 1, np.concatenate(marked)[order].astype(np.int32),
                                 np.concatenate(values)[order])
    return domain, tags, mesh, space


def _forms(domain, tags, compile_options):
    """The Taylor-Hood space, the unknown ``w = (u, p)``, the load factor, the residual and tangent
    forms (compiled), and the clamped base."""
    import basix.ufl
    import dolfinx.fem
    import ufl

    from hyperoc.cardiac.land import VENTRICLE
    from hyperoc.fem.quadrature import simplex_rule

    P2 = basix.ufl.element("Lagrange", "tetrahedron", 2, shape=(3,))
    P1 = basix.ufl.element("Lagrange", "tetrahedron", 1)
    W = dolfinx.fem.functionspace(domain, basix.ufl.mixed_element([P2, P1]))
    w = dolfinx.fem.Function(W)
    u, p = ufl.split(w)
    load = dolfinx.fem.Constant(domain, 0.0)  # the load factor s

    # Guccione on the isochoric strain, without its bulk term (TaylorHoodModel's W_rest), fibres along x.
    C_mod, bf, bt, bfs = (VENTRICLE[k] for k in ("C", "bf", "bt", "bfs"))
    Id = ufl.Identity(3)
    F = Id + ufl.grad(u)
    C = F.T * F
    J = ufl.det(F)
    Ebar = 0.5 * (ufl.det(C) ** (-1.0 / 3.0) * C - Id)
    f = ufl.as_vector((1.0, 0.0, 0.0))
    P = Id - ufl.outer(f, f)
    Ef = Ebar * f
    PEP, PEf = P * Ebar * P, P * Ef
    Q = bf * ufl.dot(f, Ef) ** 2 + bt * ufl.inner(PEP, PEP) + 2.0 * bfs * ufl.dot(PEf, PEf)
    energy = 0.5 * C_mod * (ufl.exp(Q) - 1.0) + p * (J - 1.0)

    xi, weights = simplex_rule(3, 4)  # StateModel's rule for P2 (space.quadrature(4))
    dx = ufl.Measure("dx", domain=domain, metadata={"quadrature_rule": "custom", "quadrature_points": xi,
                                                    "quadrature_weights": weights})
    ds = ufl.Measure("ds", domain=domain, subdomain_data=tags, metadata={"quadrature_degree": 4})
    v = ufl.TestFunction(W)
    vu, _ = ufl.split(v)
    N = ufl.FacetNormal(domain)
    residual = ufl.derivative(energy * dx, w, v) \
        + load * VENTRICLE["pressure"] * ufl.dot(vu, ufl.cofac(F) * N) * ds(2)
    tangent = ufl.derivative(residual, w, ufl.TrialFunction(W))
    R = dolfinx.fem.form(residual, jit_options=compile_options)
    K = dolfinx.fem.form(tangent, jit_options=compile_options)

    fdim = domain.topology.dim - 1
    V0, _ = W.sub(0).collapse()
    base = dolfinx.fem.locate_dofs_topological((W.sub(0), V0), fdim, tags.find(1))
    zero = dolfinx.fem.Function(V0)
    bc = dolfinx.fem.dirichletbc(zero, base, W.sub(0))
    return W, w, load, R, K, bc


class _Clock:
    """Seconds spent per part of the solve."""

    def __init__(self):
        self.parts = {}

    def __call__(self, part):
        clock = self

        class Span:
            def __enter__(self):
                self.t0 = time.perf_counter()

            def __exit__(self, *exc):
                clock.parts[part] = clock.parts.get(part, 0.0) + time.perf_counter() - self.t0

        return Span()


class _Linear:
    """The tangent, residual and increment vectors and MUMPS (PC lu) of a DOLFINx solve."""

    def __init__(self, comm, W, K):
        import dolfinx.fem.petsc as fpetsc
        from petsc4py import PETSc

        self.A, self.b, self.du = fpetsc.create_matrix(K), fpetsc.create_vector(W), fpetsc.create_vector(W)
        self.ksp = PETSc.KSP().create(comm)
        self.ksp.setType(PETSc.KSP.Type.PREONLY)
        self.ksp.getPC().setType(PETSc.PC.Type.LU)
        self.ksp.getPC().setFactorSolverType("mumps")

    def assemble(self, R, K, bc) -> None:
        """The tangent and minus the residual at the current ``w`` (0 on the clamped rows)."""
        import dolfinx.fem.petsc as fpetsc
        from petsc4py import PETSc

        self.A.zeroEntries()
        fpetsc.assemble_matrix(self.A, K, bcs=[bc])
        self.A.assemble()
        with self.b.localForm() as bl:
            bl.set(0.0)
        fpetsc.assemble_vector(self.b, R)
        self.b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        fpetsc.set_bc(self.b, [bc])  # u = 0 on the base: the increment is 0 there
        self.b.scale(-1.0)

    def solve(self) -> bool:
        """Factor the tangent and solve for the increment ``du``; False if MUMPS failed."""
        self.ksp.setOperators(self.A)
        self.ksp.solve(self.b, self.du)
        return self.ksp.getConvergedReason() >= 0

    def destroy(self) -> None:
        for obj in (self.ksp, self.A, self.b, self.du):
            obj.destroy()


def _steady(comm, W, w, load, R, K, bc, repeat: int) -> dict:
    """Seconds of one residual + tangent assembly and of one factorization + solve, compiled, at the
    current ``w`` and the full load: the mean of ``repeat`` repetitions, the largest over the ranks."""
    from mpi4py import MPI

    lin, load.value, parts = _Linear(comm, W, K), 1.0, {"residual + tangent": 0.0, "factor + solve": 0.0}
    for _ in range(repeat + 1):  # the first one sets up MUMPS's symbolic factorization: not counted
        t0 = time.perf_counter()
        lin.assemble(R, K, bc)
        t1 = time.perf_counter()
        lin.solve()
        t2 = time.perf_counter()
        if _:
            parts["residual + tangent"] += t1 - t0
            parts["factor + solve"] += t2 - t1
    lin.destroy()
    return {k: comm.allreduce(v / repeat, op=MPI.MAX) for k, v in parts.items()}


def _solve(comm, W, w, load, R, K, bc, clock):
    """Load stepping (`hyperoc.dynamics.statics.step_load`'s: halve a failed increment, grow back after a
    success) with full Newton steps; ``(Newton iterations per accepted increment, rejected iterations)``."""
    from mpi4py import MPI

    lin = _Linear(comm, W, K)
    owned = W.dofmap.index_map.size_local * W.dofmap.index_map_bs
    blocks = []
    for k in range(2):
        _, dofs = W.sub(k).collapse()
        dofs = np.asarray(dofs)
        blocks.append(dofs[dofs < owned])
    inf = lambda a, idx: comm.allreduce(float(np.abs(a[idx]).max()) if idx.size else 0.0, op=MPI.MAX)

    def newton(s):
        load.value = s
        for it in range(1, MAX_ITER + 1):
            with clock("assembly"):
                lin.assemble(R, K, bc)
            with clock("solve"):
                solved = lin.solve()
            if not solved:
                return it, False
            d, x = lin.du.getArray(readonly=True), w.x.array[:owned]
            if not comm.allreduce(bool(np.all(np.isfinite(d))), op=MPI.LAND):
                return it, False
            small = all(inf(d, i) <= RTOL * inf(x + d, i) + ATOL for i in blocks)
            w.x.array[:owned] += d
            w.x.scatter_forward()
            if small:
                return it, True
        return MAX_ITER, False

    iters, rejected, s_done, ds, cuts = [], 0, 0.0, 1.0 / STEPS, 0
    while s_done < 1.0:
        s = s_done + ds if s_done + ds < 1.0 - 1e-12 else 1.0
        saved = w.x.array.copy()
        it, ok = newton(s)
        if ok:
            iters.append(it)
            s_done, ds = s, min(2 * ds, 1.0 / STEPS)
        elif cuts < CUTBACKS:
            w.x.array[:] = saved
            ds, cuts, rejected = ds / 2, cuts + 1, rejected + it
        else:
            raise RuntimeError(f"Newton failed at load factor {s}")
    lin.destroy()
    return iters, rejected


def _hyperoc_layout(W, w, space, comm):
    """The solution in hyperoc's numbering, on rank 0 (None elsewhere): the unknown ``x = (free
    displacement dofs, vertex pressures)``, the number of free displacement dofs, and the nodal
    displacement (num_nodes, 3)."""
    out = []
    for k in range(2):
        Vk, dofs = W.sub(k).collapse()
        n = Vk.dofmap.index_map.size_local
        coords = Vk.tabulate_dof_coordinates()[:n]
        values = w.x.array[np.asarray(dofs)].reshape(-1, Vk.dofmap.index_map_bs)[:n]
        out.append(comm.gather((coords, values), root=0))
    if comm.rank != 0:
        return None, None, None
    from scipy.spatial import cKDTree

    from hyperoc.mechanics.constraints import constrain

    def by_node(parts, nodes):
        coords, values = (np.concatenate(a) for a in zip(*parts))
        dist, index = cKDTree(coords).query(nodes)
        if dist.max() > 1e-9:
            raise RuntimeError(f"a hyperoc node is not a DOLFINx dof ({dist.max():.3g} mm away)")
        return values[index]

    u = by_node(out[0], space.nodes)
    p = by_node(out[1], space.mesh.points).ravel()
    free = constrain(space, "base", {}, True).free  # hyperoc's reduced numbering (StateModel.free)
    return np.concatenate([u.ravel()[free], p]), int(free.size), u


def worker(args) -> None:
    """One DOLFINx solve on MPI.COMM_WORLD; rank 0 writes the JSON record ``args.out``."""
    import dolfinx_solver  # noqa: F401  (loads MPI before dolfinx)
    from mpi4py import MPI

    from hyperoc.cardiac.land import VENTRICLE

    comm = MPI.COMM_WORLD
    cache = None if args.warm_cache else tempfile.mkdtemp(prefix="ffcx-") if comm.rank == 0 else None
    cache = comm.bcast(cache, root=0)
    options = {} if cache is None else {"cache_dir": cache}
    comm.Barrier()
    t0 = time.perf_counter()
    domain, tags, mesh, space = _dolfinx_mesh(comm, args.refinements)
    t_mesh = time.perf_counter() - t0
    t1 = time.perf_counter()
    W, w, load, R, K, bc = _forms(domain, tags, options)
    t_forms = comm.allreduce(time.perf_counter() - t1, op=MPI.MAX)
    setup = comm.allreduce(time.perf_counter() - t0, op=MPI.MAX)
    t_mesh = comm.allreduce(t_mesh, op=MPI.MAX)
    clock = _Clock()
    comm.Barrier()
    t0 = time.perf_counter()
    iters, rejected = _solve(comm, W, w, load, R, K, bc, clock)
    seconds = comm.allreduce(time.perf_counter() - t0, op=MPI.MAX)
    split = {k: comm.allreduce(v, op=MPI.MAX) for k, v in clock.parts.items()}
    memory = comm.gather(_peak_mb(), root=0)
    x, n_u, u = _hyperoc_layout(W, w, space, comm)
    w.x.array[:] = 0.0
    steady = _steady(comm, W, w, load, R, K, bc, args.repeat)
    size = W.dofmap.index_map.size_global * W.dofmap.index_map_bs
    if comm.rank == 0:
        if cache is not None:
            shutil.rmtree(cache, ignore_errors=True)
        values = {}
        for name, X in (("z_endo", VENTRICLE["endo_apex"]), ("z_epi", VENTRICLE["epi_apex"])):
            dist = np.linalg.norm(space.nodes - np.asarray(X), axis=1)  # the apexes are mesh vertices
            a = int(np.argmin(dist))
            if dist[a] > 1e-9:
                raise RuntimeError(f"{X} is not a node of the mesh")
            values[name] = float(X[2] + u[a, 2])
        record = {"problem": "ventricle", "refinements": args.refinements, "serial": False, "path": "dolfinx",
                  "ranks": comm.size, "unknowns": int(x.size), "n_u": n_u, "system_size": int(size),
                  "values": values, "newton_iterations": iters, "rejected_iterations": rejected,
                  "setup_seconds": setup, "mesh_seconds": t_mesh, "solve_seconds": seconds, "peak_mb": memory,
                  "forms_seconds": t_forms, "split_seconds": split, "steady": steady, "u": x.tolist()}
        Path(args.out).write_text(json.dumps(record))


def steady_hyperoc(args) -> None:
    """hyperoc's distributed kernels and MUMPS on MPI.COMM_WORLD (`hyperoc.distributed.statics`), at u = 0
    and the full load: the first residual + tangent evaluation (JAX compilation included), then the
    mean of ``args.repeat`` compiled ones (kernels, assembly) and of as many factorizations + solves;
    rank 0 writes the JSON record ``args.out``."""
    import math

    from mpi4py import MPI

    from hyperoc.cardiac.land import ventricle_problem
    from hyperoc.distributed.statics import DistributedStatics

    comm = MPI.COMM_WORLD
    model, follower = ventricle_problem(MESH_SIZE, bulk_modulus=math.inf, volumetric="taylor-hood", isochoric=True,
                                        refinements=args.refinements)
    dist = DistributedStatics(model, follower, comm=comm, constrained=False)
    kernels, layout = dist._kernels, dist.layout
    xl = np.zeros(dist.local.n)
    evaluate = lambda: (np.asarray(kernels["force"](xl, 1.0)), np.asarray(kernels["blocks"](xl, 0.0, 1.0)))
    comm.Barrier()
    t0 = time.perf_counter()
    f, blocks = evaluate()
    first = comm.allreduce(time.perf_counter() - t0, op=MPI.MAX)
    layout.factor(blocks)  # MUMPS's symbolic factorization: not counted
    layout.solve(-layout.add(f))
    layout.split = {}
    for _ in range(args.repeat):
        with layout.clock("kernels"):
            f, blocks = evaluate()
        r = layout.add(f)
        layout.factor(blocks)
        layout.solve(-r)
    split = {k: v / args.repeat for k, v in layout.slowest_split().items()}
    if comm.rank == 0:
        record = {"path": "hyperoc", "ranks": comm.size, "unknowns": int(model.n), "first_seconds": first,
                  "steady": {"residual + tangent": split["kernels"] + split["assembly"], "kernels": split["kernels"],
                             "factor + solve": split["solve"]}}
        Path(args.out).write_text(json.dumps(record))


# --- the bench (plain python, starts the runs) -------------------------------------------------------

def _mpiexec() -> str:
    return shutil.which("mpiexec", path=os.path.dirname(sys.executable)) or "mpiexec"


STEADY_COLUMNS = ["level", "unknowns", "path", "ranks", "kernel compilation (s)", "residual + tangent (s)",
                  "of which JAX kernels (s)", "factor + solve (s)", "residual + tangent / factor + solve"]


def _environment() -> dict:
    """The environment of the runs: this repository's hyperoc first on the path (the environment may
    hold another copy installed in development mode)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])])
    return env


def run(level: int, path: str, ranks: int | None, folder: Path, args) -> dict:
    """One run in its own process tree: a hyperoc solve, serial (ranks None) or distributed on ``ranks``
    MPI ranks, a DOLFINx solve (``path`` "dolfinx") or hyperoc's steady-state timing ("hyperoc-steady")."""
    out = folder / f"L{level}-{path}-{ranks or 'serial'}.json"
    if path in ("dolfinx", "hyperoc-steady"):
        cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", path, "--refinements", str(level),
               "--repeat", str(args.repeat), "--out", str(out)] + (["--warm-cache"] if args.warm_cache else [])
    else:
        cmd = [sys.executable, "-m", "hyperoc.app.distributed_statics", "--problem", "ventricle", "--refinements",
               str(level), "--out", str(out)] + (["--serial"] if ranks is None else [])
    if ranks is not None:
        cmd = [_mpiexec(), "-n", str(ranks), *cmd]
    subprocess.run(cmd, check=True, env=_environment())
    return json.loads(out.read_text())


def compare(record: dict, serial: dict, n_u: int) -> tuple[float, float]:
    """``(max |z_apex - z_apex,serial| (mm), max |u - u_serial| / max |u_serial|)`` over the displacements."""
    dz = max(abs(record["values"][k] - serial["values"][k]) for k in serial["values"])
    u, u_ref = np.asarray(record["u"])[:n_u], np.asarray(serial["u"])[:n_u]
    return dz, float(np.abs(u - u_ref).max() / np.abs(u_ref).max())


def split(record: dict) -> str | None:
    parts = record.get("split_seconds") or {}
    if not parts:
        return None
    residual = parts.get("kernels", 0.0) + parts.get("assembly", 0.0)
    return f"{residual:.2f} / {parts['solve']:.2f}"


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--refinements", default="0", help="comma-separated levels (0: 1,706 unknowns, 1: 11,569)")
    parser.add_argument("--ranks", default="1,2", help="comma-separated rank counts of the MPI runs")
    parser.add_argument("--warm-cache", action="store_true",
                        help="DOLFINx: use FFCx's default cache (forms compiled once for all runs)")
    parser.add_argument("--results", default="bench_dolfinx", help="results file stem")
    parser.add_argument("--repeat", type=int, default=5,
                        help="compiled residual + tangent evaluations and factorizations timed per run (second table)")
    parser.add_argument("--worker", choices=("dolfinx", "hyperoc-steady"), help=argparse.SUPPRESS)
    parser.add_argument("--out", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        args.refinements = int(args.refinements)
        (worker if args.worker == "dolfinx" else steady_hyperoc)(args)
        return
    from results import Table, command_line, write_results

    table = Table("Land problem 2 (Taylor-Hood, incompressible): hyperoc (JAX kernels) vs DOLFINx (UFL, FFCx), "
                  "MUMPS", COLUMNS,
                  "Unknowns: free displacement dofs and vertex pressures (DOLFINx's matrix also holds the clamped "
                  "dofs, as identity rows). Set-up: mesh and model or spaces and forms (DOLFINx: FFCx compilation "
                  "included); solve: all load steps (hyperoc: JAX compilation included). Residual + tangent: JAX "
                  "kernels and assembly (hyperoc distributed), form assembly (DOLFINx); factor + solves: PETSc "
                  "MUMPS. Differences against hyperoc's serial path of the same level (its own row: 0).")
    ranks = [int(r) for r in args.ranks.split(",")]
    where = subprocess.run([sys.executable, "-c", "import hyperoc; print(hyperoc.__file__)"], env=_environment(),
                           check=True, capture_output=True, text=True).stdout.strip()
    if not Path(where).resolve().is_relative_to(ROOT):
        raise SystemExit(f"the runs would import hyperoc from {where}, not from {ROOT}")
    steady = Table("One Newton iteration, compiled: residual + tangent against factorization + solve (u = 0, full "
                   "load)", STEADY_COLUMNS,
                   f"The mean of {args.repeat} repetitions after a first one, the largest over the ranks. Kernel "
                   "compilation: hyperoc, the first residual + tangent evaluation less a compiled one (JAX tracing "
                   "and XLA); DOLFINx, building the Taylor-Hood space and the two forms (UFL, FFCx, the C compiler). "
                   "Residual + tangent: hyperoc, its JAX kernels on the rank's cells, the ghost scatter and the COO "
                   "insertion into the PETSc matrix; DOLFINx, assemble_vector and assemble_matrix (its generated "
                   "kernels and the insertion). Factor + solve: PETSc MUMPS, numeric factorization and one solve.")
    loads = []  # the machine's load average (1 min) at the start and the end of each level
    with tempfile.TemporaryDirectory() as tmp:
        for level in map(int, args.refinements.split(",")):
            loads.append([level, os.getloadavg()[0]])
            serial = run(level, "hyperoc", None, Path(tmp), args)
            records = [("hyperoc serial", serial)]
            records += [("hyperoc distributed", run(level, "hyperoc", r, Path(tmp), args)) for r in ranks]
            records += [("DOLFINx", run(level, "dolfinx", r, Path(tmp), args)) for r in ranks]
            timings = [run(level, "hyperoc-steady", r, Path(tmp), args) for r in ranks]
            loads[-1].append(os.getloadavg()[0])
            n_u = next(r["n_u"] for _, r in records if "n_u" in r)
            for name, r in records:
                its = int(sum(r["newton_iterations"])) + int(r["rejected_iterations"])
                dz, du = compare(r, serial, n_u)
                table.add(level, r["unknowns"], name, r["ranks"], r["setup_seconds"], r["solve_seconds"], its,
                          r["solve_seconds"] / its, split(r), max(r["peak_mb"]), r["values"]["z_endo"],
                          r["values"]["z_epi"], dz, du)
            for name, r in [("hyperoc distributed", t) for t in timings] + \
                    [(name, r) for name, r in records if name == "DOLFINx"]:
                t = r["steady"]
                compile_ = r["first_seconds"] - t["kernels"] if "first_seconds" in r else r["forms_seconds"]
                steady.add(level, r["unknowns"], name, r["ranks"], compile_, t["residual + tangent"], t.get("kernels"),
                           t["factor + solve"], t["residual + tangent"] / t["factor + solve"])
    cpus = len(os.sched_getaffinity(0))
    table.notes += f" Load average (1 min) on the {cpus} CPUs at the start and the end of each level: " + \
        ", ".join(f"level {level}: {start:.1f}, {end:.1f}" for level, start, end in loads) + \
        " (the runs share the machine with whatever else runs on it)."
    write_results(args.results, command_line(), [table.as_dict(), steady.as_dict()])


if __name__ == "__main__":
    main()
