#!/usr/bin/env python3
"""Where the wall time of a plastic step of the biaxial test goes:
Gauss-point kernel (EhlersMaterial.update), strain evaluation at the Gauss points,
residual assembly, Jacobian assembly and the linear solve (MUMPS LU: PETSc events
PCSetUp, the factorisation SNES triggers before KSPSolve, plus KSPSolve),
on the ranks of the run. Aim: the kernel under 30 % of the step.

The default demo set-up (50 mm x 100 mm, h = 2.5 mm, P2/P1) is consolidated and then
compressed in --steps plastic steps of the hardening branch (every Gauss point flowing);
times are summed over those steps and reduced with MPI MAX (the slowest rank sets the
pace). Writes --out/profile_<ranks>.json.

    python3 benchmarks/ehlers/biaxial_profile.py
    mpirun -n 2 python3 benchmarks/ehlers/biaxial_profile.py
"""
import argparse
import json
import os
import time

from mpi4py import MPI
from petsc4py import PETSc

from cosserat_fenicsx.scenes.biaxial import BiaxialSettings, BiaxialTest


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default="results/profile")
    p.add_argument("--cell-size", type=float, default=2.5e-3)
    p.add_argument("--steps", type=int, default=10, help="plastic steps timed (hardening branch)")
    args = p.parse_args()
    comm = MPI.COMM_WORLD
    os.makedirs(args.out, exist_ok=True)
    # 10 steps of 0.2 %: hardening, far from the peak at about 4 %
    s = BiaxialSettings(cell_size=args.cell_size, steps=args.steps, axial_strain=0.002 * args.steps)
    test = BiaxialTest(comm, s, verbose=False)
    solver = test.solver.solver
    cb_owner = test.problem
    timers = {"residual_total": 0.0, "jacobian_assembly": 0.0, "callback_update": 0.0}
    original_residual, original_jacobian = solver.residual, solver.jacobian
    original_before = cb_owner.before_residual

    def timed(name, fn):
        def wrapper(*a):
            t0 = time.perf_counter()
            out = fn(*a)
            timers[name] += time.perf_counter() - t0
            return out
        return wrapper

    cb_owner.before_residual = timed("callback_update", original_before)
    solver.snes.setFunction(timed("residual_total", original_residual), solver.b)
    solver.snes.setJacobian(timed("jacobian_assembly", original_jacobian), solver.A)
    PETSc.Log.begin()
    ksp_event = PETSc.Log.Event("KSPSolve")
    pc_event = PETSc.Log.Event("PCSetUp")
    mark = {}

    def on_step(row):
        if row["step"] == s.consolidation_steps:   # start timing at the first plastic step of phase 2
            mark.update(timers)
            mark["kernel"] = test.zoned.kernel_time
            mark["ksp"] = ksp_event.getPerfInfo()["time"]
            mark["pc"] = pc_event.getPerfInfo()["time"]
            mark["wall"] = time.perf_counter()

    test.run(on_step)
    wall = time.perf_counter() - mark["wall"]
    kernel = test.zoned.kernel_time - mark["kernel"]
    ksp = ksp_event.getPerfInfo()["time"] - mark["ksp"]
    pc = pc_event.getPerfInfo()["time"] - mark["pc"]
    update = timers["callback_update"] - mark["callback_update"]
    residual = timers["residual_total"] - mark["residual_total"] - update
    jacobian = timers["jacobian_assembly"] - mark["jacobian_assembly"]
    rows = [r for r in test.history if r["phase"] == 2]
    parts = {"kernel": kernel, "strain_evaluation_and_copy": update - kernel, "residual_assembly": residual,
             "jacobian_assembly": jacobian, "linear_solve": ksp + pc, "of_which_lu_factorisation": pc}
    parts = {k: comm.allreduce(v, op=MPI.MAX) for k, v in parts.items()}
    wall = comm.allreduce(wall, op=MPI.MAX)
    counted = sum(v for k, v in parts.items() if k != "of_which_lu_factorisation")
    parts["other (SNES, line search, history, reactions)"] = wall - counted
    result = {"ranks": comm.size, "cell_size": args.cell_size, "plastic_steps": len(rows),
              "newton_iterations": sum(r["newton_iterations"] for r in rows),
              "plastic_fraction_min": min(r["plastic_fraction"] for r in rows),
              "gauss_points": comm.allreduce(len(test.points)),
              "dofs": test.problem.W.dofmap.index_map.size_global * test.problem.W.dofmap.index_map_bs,
              "wall_time": wall, "seconds": parts,
              "percent": {k: 100.0 * v / wall for k, v in parts.items()}}
    if comm.rank == 0:
        with open(os.path.join(args.out, f"profile_{comm.size}.json"), "w") as f:
            json.dump(result, f, indent=2)
        print(f"{comm.size} rank(s), {result['gauss_points']} Gauss points, {result['dofs']} dofs, "
              f"{len(rows)} plastic steps, {result['newton_iterations']} Newton iterations, {wall:.2f} s")
        for k, v in parts.items():
            print(f"  {k:48s} {v:8.3f} s  {100 * v / wall:5.1f} %")


if __name__ == "__main__":
    main()
