"""The cardiac elastodynamics benchmark's domain: the committed reference mesh against hyperoc's own Gmsh meshes
(`hyperoc.cardiac.benchmark_geometry`), by vertex and cell counts, wall volume and cavity volume, each against
the exact value of the domain (an integral over the meridian section, below).

    python bench/bench_benchmark_geometry.py

Writes ``bench/results/bench_benchmark_geometry.json`` (`bench/results.py`).

Exact volumes. The wall is the solid of revolution about ``x`` of the meridian section between the two
ellipses ``r_k(x) = r_s,k sqrt(1 - x^2 / r_l,k^2)`` and below the base segment ``r = slope (x_apex - x)``:
``V_wall = pi int (min(r_epi, cone)^2 - min(r_endo, cone)^2) dx`` over where positive; the cavity volume is
``pi int_{-r_l}^{x_rim} r_endo(x)^2 dx`` (closed by the rim plane, as `cavity_volume` measures it).
"""

from __future__ import annotations

import math
import time

import numpy as np
from scipy.integrate import quad

from hyperoc.cardiac import benchmark_geometry as bg
from hyperoc.fem.spaces import VectorSpace
from results import Table, command_line, write_results


def exact_volumes() -> tuple[float, float]:
    """(wall, cavity) volumes of the benchmark domain, m^3."""
    apex, slope, _ = bg._base_cone()

    def radius(axes, x):
        rs, rl = axes
        return rs * math.sqrt(max(0.0, 1.0 - (x / rl) ** 2))

    def section(x):
        cone = slope * (apex - x)
        return max(0.0, min(radius(bg.EPI, x), cone)) ** 2 - max(0.0, min(radius(bg.ENDO, x), cone)) ** 2

    breaks = [bg.ENDO[1] * -1, bg.BASE_X[1], bg.BASE_X[0]]
    wall = math.pi * quad(section, -bg.EPI[1], apex, points=breaks, limit=200, epsabs=1e-14)[0]
    cavity = math.pi * quad(lambda x: radius(bg.ENDO, x) ** 2, -bg.ENDO[1], bg.BASE_X[0], epsabs=1e-14)[0]
    return wall, cavity


def main() -> None:
    wall, cavity = exact_volumes()
    out = Table("The benchmark's domain: reference mesh and hyperoc's Gmsh meshes",
                ["mesh", "h (mm)", "vertices", "cells", "wall volume (mm^3)", "error", "P2 wall error",
                 "cavity volume (mL)", "error", "build (s)"],
                notes=f"exact wall volume {wall * 1e9:.1f} mm^3, exact cavity volume {cavity * 1e6:.4f} mL; "
                      "volumes of the straight cells; P2: the isoparametric cells of the curved mesh")
    candidates = [("reference (toolkit, committed)", 5.0, bg.reference_mesh)]
    candidates += [(f"hyperoc benchmark_mesh({h:g})", h * 1e3, lambda h=h: bg.benchmark_mesh(h))
                   for h in (0.012, 0.005, 0.0035)]
    for name, h, build in candidates:
        t0 = time.perf_counter()
        mesh = build()
        seconds = time.perf_counter() - t0
        p2 = VectorSpace(mesh, 2).quadrature(4).wdx.sum() if mesh.is_curved else float("nan")
        v_cavity = bg.cavity_volume(mesh)
        out.add(name, h, len(mesh.points), mesh.num_cells, mesh.volume() * 1e9, f"{mesh.volume() / wall - 1:+.2%}",
                f"{p2 / wall - 1:+.3%}" if mesh.is_curved else "-", v_cavity * 1e6, f"{v_cavity / cavity - 1:+.2%}",
                round(seconds, 2))
    write_results("bench_benchmark_geometry", command_line(), [out.as_dict()])


if __name__ == "__main__":
    np.seterr(all="raise")
    main()
