# YADE side of benchmarks/femdem/femdem_yade.py (run by YADE, not by python3). Two uses:
#
#   yade -n -x -j1 femdem_yade_driver.py export RVE.yade.gz EXPORT.json
#       the RVE of YADE's FEMxDEM example (0.yade.gz, made by its prepareRVE.py) as JSON:
#       radii, centres, masses, inertias, periodic cell, time step, friction, the stiffness of
#       every contact (Ip2_FrictMat_FrictMat_FrictPhys: kn = 2 E Ra Rb / (Ra + Rb), ks = nu kn),
#       local damping, stress [Pa] and out-of-plane thickness hSize[2,2] [m].
#
#   NP=2 NSTEPS=5 yade -n -x -j1 femdem_yade_driver.py run biaxialSmooth.py RECORD.jsonl
#       (in a folder holding 0.yade.gz and yadeimport.py, with PYTHONPATH and LD_LIBRARY_PATH
#       set for python3-escript and YADE's py/FEMxDEM) runs YADE's example biaxialSmooth.py
#       with only what Python 3 and this machine need: `file` -> `open`, a pool of NP worker
#       processes instead of 16, NSTEPS increments instead of 100, and no final dump of the
#       512 packings. The example's own code is executed unchanged otherwise; timing and
#       counting wrap its MultiScale methods from outside (msFEM2D is not edited):
#         MultiScale.solve (one increment's Newton: passes over the cells, wall/CPU time),
#         MultiScale.applyStrain_getStressTangentDEM (one pass: shear2D + getStressAndTangent2D
#         on every cell; the DEM steps of the pass are those shear2D runs,
#         ns = int(max(1e5 max|D|, 2)) per cell, counted from the same D).
#       One JSON line per increment goes to RECORD.jsonl ("kind": "increment"), plus one for the
#       set-up ("kind": "setup": pool start, 512 scenes loaded, first stress and tangent).
#       CPU seconds are those of the YADE process and its pool workers (/proc, utime + stime).
import json
import os
import sys
import time

MODE = sys.argv[1]


def tree_cpu():
    """utime + stime [s] of this process and its live children (the pool workers)."""
    tick = os.sysconf("SC_CLK_TCK")
    me = os.getpid()
    total = 0.0
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            with open(f"/proc/{pid}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(pid) == me or int(fields[1]) == me:        # fields[1]: parent pid
            total += (int(fields[11]) + int(fields[12])) / tick
    return total


if MODE == "export":
    src, dst = sys.argv[2], sys.argv[3]
    O.load(src)
    h = O.cell.hSize
    st = getStress()
    contacts = [i for i in O.interactions if i.isReal]
    data = dict(radius=[b.shape.radius for b in O.bodies], x=[b.state.pos[0] for b in O.bodies],
                y=[b.state.pos[1] for b in O.bodies], mass=[b.state.mass for b in O.bodies],
                inertia=[b.state.inertia[2] for b in O.bodies],
                h=[[h[0, 0], h[0, 1]], [h[1, 0], h[1, 1]]], thickness=h[2, 2], dt=O.dt,
                friction=contacts[0].phys.tangensOfFrictionAngle if contacts else float("nan"),
                contact_kn=[i.phys.kn for i in contacts], contact_ks=[i.phys.ks for i in contacts],
                young=O.materials[0].young, poisson=O.materials[0].poisson,
                damping=[e for e in O.engines if type(e).__name__ == "NewtonIntegrator"][0].damping,
                engines=[type(e).__name__ for e in O.engines],
                stress_pa=[[st[0, 0], st[0, 1]], [st[1, 0], st[1, 1]]])
    with open(dst, "w") as fh:
        json.dump(data, fh)
    sys.stdout.flush()
    os._exit(0)

if MODE != "run":
    raise SystemExit(f"femdem_yade_driver.py: unknown mode {MODE!r} (export or run)")

script, record_path = sys.argv[2], sys.argv[3]
NP, NSTEPS = int(os.environ.get("NP", "2")), int(os.environ.get("NSTEPS", "5"))
import builtins
import numpy
builtins.file = open                  # Python 3: the example opens its output with file()
import msFEM2D

record = open(record_path, "w")


def emit(**row):
    record.write(json.dumps(row) + "\n")
    record.flush()


counters = dict(passes=0, dem_steps=0, pass_wall=0.0)
_apply = msFEM2D.MultiScale.applyStrain_getStressTangentDEM
_solve = msFEM2D.MultiScale.solve
_init = msFEM2D.MultiScale.__init__


def apply_counted(self, st=None):
    D = numpy.array(st.toListOfTuples()).reshape(-1, 4)
    # shear2D's own step count per cell (simDEM.shear2D), from the same strain
    counters["dem_steps"] += int(sum(int(max(1e5 * numpy.max(numpy.abs(d)), 2)) for d in D))
    counters["passes"] += 1
    t0 = time.time()
    out = _apply(self, st=st)
    counters["pass_wall"] += time.time() - t0
    return out


def solve_timed(self, iter_max=100):
    for k in counters:
        counters[k] = 0
    t0, c0, load0 = time.time(), tree_cpu(), open("/proc/loadavg").read().split()[0]
    u = _solve(self, iter_max=iter_max)
    emit(kind="increment", wall=time.time() - t0, cpu=tree_cpu() - c0, passes=counters["passes"],
         newton_iterations=counters["passes"] - 1, dem_steps=counters["dem_steps"],
         pass_wall=counters["pass_wall"], load1_start=float(load0),
         load1_end=float(open("/proc/loadavg").read().split()[0]), time=time.time())
    return u


def init_timed(self, *a, **kw):
    t0 = time.time()
    _init(self, *a, **kw)
    scenes = self._MultiScale__scenes            # one serialised YADE scene per Gauss point
    emit(kind="setup", wall=time.time() - t0, cpu_since_start=tree_cpu(), time=time.time(),
         cells=len(scenes), scene_bytes_per_cell=len(scenes[0]))


msFEM2D.MultiScale.applyStrain_getStressTangentDEM = apply_counted
msFEM2D.MultiScale.solve = solve_timed
msFEM2D.MultiScale.__init__ = init_timed

s = open(script).read()
edits = [("nump = 16", f"nump = {NP}"),
         ("while t < 100:", f"while t < {NSTEPS}:"),
         ("prob.getCurrentPacking(pos=(), time=t, prefix='./result/packing/')", "pass  # 512 packings not written"),
         ("\tt += 1\n", "\tt += 1\n\t_t_inc = time.time()\n")]     # the increment's start, for _emit_full
for old, new in edits:
    if old not in s:
        raise SystemExit(f"femdem_yade_driver.py: {script} has changed, cannot find {old!r}")
    s = s.replace(old, new, 1)
# the example's own per-increment outputs (stress projection, void ratio and fabric passes over
# the cells, saveGauss, saveVTK) stay in; the time of a whole increment is logged as well
vtk = '\tsaveVTK("./result/vtk/biaxialSmooth_%d.vtu" % t, disp=disp, shear=shear, e=vR)\n'
if vtk not in s:
    raise SystemExit(f"femdem_yade_driver.py: {script} has changed, cannot find {vtk!r}")
s = s.replace(vtk, vtk + "\t_emit_full(time.time() - _t_inc)\n", 1)
t_start = time.time()
g = dict(__name__="__main__", __file__=script,
         _emit_full=lambda w: emit(kind="increment_with_output", wall=w, time=time.time()))
exec(compile(s, script, "exec"), g)
emit(kind="end", wall=time.time() - t_start, cpu=tree_cpu(), time=time.time())
record.close()
sys.stdout.flush()
os._exit(0)
