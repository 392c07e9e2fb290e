# YADE side of benchmarks/dem/dem_speed.py (run by YADE, not by python3):
#   yade -n -x -j1 benchmarks/dem/dem_yade_driver.py PACKING.yade.gz NSTEPS EXPORT.json KN KS TOL MAXSOLVE DT
# (DT = 0: keep the packing's O.dt)
# Loads a packing made by ../shared/peer-yade/prep_bench.py, forces a constant contact
# stiffness (kn, ks) on every contact (so both codes use the same linear Cundall-Strack law),
# exports the packing (radii, positions, cell, masses, dt, friction) for demcell, then
# 1. times NSTEPS steps under the velocity gradient of peer-yade/run_bench.py
#    (1e-5 strain per step, xx extension + yy compression, NewtonIntegrator damping 0.7);
# 2. times one quasi-static solve from the exported state with the shear forces zeroed (as
#    demcell starts): the same strain rate for 10 steps (1e-4 strain), then relaxation at
#    fixed cell until max unbalanced force / mean contact force <= TOL
#    (unbalancedForce(useMaxForce=True)), checked every 50 steps; prints the stress (N/m).
# Prints one line "YADE_RESULT {json}".
import json
import os
import resource
import sys
import time

f, NS, export = sys.argv[1], int(sys.argv[2]), sys.argv[3]
KN, KS, TOL = float(sys.argv[4]), float(sys.argv[5]), float(sys.argv[6])
MAXSOLVE, DT = int(sys.argv[7]), float(sys.argv[8])


def cpu():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


O.load(f)
O.engines = [
    ForceResetter(),
    InsertionSortCollider([Bo1_Sphere_Aabb()]),
    InteractionLoop([Ig2_Sphere_Sphere_ScGeom()],
                    [Ip2_FrictMat_FrictMat_FrictPhys(kn=MatchMaker(algo='val', val=KN),
                                                     ks=MatchMaker(algo='val', val=KS))],
                    [Law2_ScGeom_FrictPhys_CundallStrack()]),
    NewtonIntegrator(damping=.7)
]
for i in O.interactions:
    if i.isReal:
        i.phys.kn = KN
        i.phys.ks = KS
if DT > 0:
    O.dt = DT
mu = tan(O.bodies[0].material.frictionAngle)
h = O.cell.hSize
data = dict(radius=[b.shape.radius for b in O.bodies], x=[b.state.pos[0] for b in O.bodies],
            y=[b.state.pos[1] for b in O.bodies], mass=[b.state.mass for b in O.bodies],
            h=[[h[0, 0], h[0, 1]], [h[1, 0], h[1, 1]]], dt=O.dt, friction=mu)
with open(export, 'w') as fh:
    json.dump(data, fh)
if NS < 2:            # export only
    sys.stdout.flush()
    os._exit(0)

snap = '/tmp/_dem_yade_snap_%d.yade' % len(O.bodies)
O.save(snap)
rate = 1e-5 / O.dt
O.cell.velGrad = Matrix3(rate, 0, 0, 0, -rate, 0, 0, 0, 0)
O.run(200, True)  # warm-up
c = [O.interactions.countReal()]
t0 = time.time(); c0 = cpu(); i0 = O.iter
O.run(NS // 2, True); c.append(O.interactions.countReal())
O.run(NS - NS // 2, True); c.append(O.interactions.countReal())
wall = time.time() - t0; dc = cpu() - c0; n = O.iter - i0
cps = sum(c) / len(c)
res = dict(n=len(O.bodies), steps=n, wall=wall, cpu=dc, steps_per_s=n / wall, steps_per_cpu_s=n / dc,
           contacts_per_step=cps, contact_updates_per_s=n / wall * cps,
           contact_updates_per_cpu_s=n / dc * cps, stress_yy=getStress()[1, 1])
print('YADE_TIMING ' + json.dumps(res), flush=True)

# one quasi-static solve from the exported state
O.load(snap)
if DT > 0:
    O.dt = DT
for i in O.interactions:
    if i.isReal:
        i.phys.kn = KN
        i.phys.ks = KS
        i.phys.shearForce = Vector3.Zero   # demcell re-detects contacts without shear history
O.engines = [
    ForceResetter(),
    InsertionSortCollider([Bo1_Sphere_Aabb()]),
    InteractionLoop([Ig2_Sphere_Sphere_ScGeom()],
                    [Ip2_FrictMat_FrictMat_FrictPhys(kn=MatchMaker(algo='val', val=KN),
                                                     ks=MatchMaker(algo='val', val=KS))],
                    [Law2_ScGeom_FrictPhys_CundallStrack()]),
    NewtonIntegrator(damping=.7)
]
O.run(1, True)
t0 = time.time(); c0 = cpu(); i0 = O.iter
O.cell.velGrad = Matrix3(rate, 0, 0, 0, -rate, 0, 0, 0, 0)
O.run(10, True)
O.cell.velGrad = Matrix3.Zero
ok = False
while O.iter - i0 < MAXSOLVE:
    O.run(50, True)
    if unbalancedForce(True) <= TOL:
        ok = True
        break
st = getStress()
th = O.cell.hSize[2, 2]                    # 2D stress per unit thickness [N/m]
res.update(solve_stress=[[st[0, 0] * th, st[0, 1] * th], [st[1, 0] * th, st[1, 1] * th]])
res.update(solve_steps=O.iter - i0, solve_wall=time.time() - t0, solve_cpu=cpu() - c0, solve_converged=ok,
           solve_unbalanced=unbalancedForce(True), solve_contacts=O.interactions.countReal(),
           maxrss_kb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
print('YADE_RESULT ' + json.dumps(res), flush=True)
