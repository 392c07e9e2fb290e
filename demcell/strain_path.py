"""A cell loaded as a FEM x DEM Gauss point loads it: the deformation gradient imposed whole.

``strain_path_step`` drives one increment of a biaxial test under full strain control: every
trial goes straight from the committed state to the target F (001 eq. 7), as the macro
Newton's trials do, and the lateral component F[lat, lat] is found by a secant iteration
until the lateral stress is the confining one. The stress servo of ``DemCell.solve`` adjusts
F while the cell relaxes instead; a frictional packing is path dependent, and the two controls
differ by about 1-2 % in the stress ratio before the peak (demos/dem_cell.py
--lateral-control).
"""


#: the lateral trials stay within this many times the axial increment of the committed
#: lateral component: a granular cell's lateral strain rate is at most a few times the
#: axial one (dilatancy), and an unbounded secant step across a flat stretch of the
#: response (sliding, a loose cell) would give a trial with det F <= 0
MAX_LATERAL_RATIO = 6.0


def strain_path_step(cell, F, lat, lateral_stress, rtol=1e-4, max_iterations=30):
    """One increment of `cell` (a DemCell) to the 2x2 deformation gradient F, its lateral
    component F[lat, lat] (lat = 0 or 1) found by a secant iteration until the Cauchy stress
    sigma_lat,lat equals `lateral_stress` [N/m] to `rtol` (relative), at most
    `max_iterations` secant updates, each trial within MAX_LATERAL_RATIO times the axial
    increment of the committed F[lat, lat]. The cell is left at the trial of the smallest
    lateral-stress error (re-solved if it was not the last), not committed. Returns the
    SolveResult of that trial, its `steps` the DEM steps of all trials."""
    def residual(f):
        cell.rollback()
        trial = F.copy()
        trial[lat, lat] = f
        cell.set_deformation(trial)
        result = cell.solve()
        return cell.cauchy_stress()[lat, lat] - lateral_stress, result

    steps = 0
    committed = cell.deformation_gradient()
    f0 = committed[lat, lat]
    axial = abs(F[1 - lat, 1 - lat] - committed[1 - lat, 1 - lat])
    f1 = f0 + 0.3 * axial + 1e-12
    low, high = f0 - MAX_LATERAL_RATIO * axial - 1e-12, f0 + MAX_LATERAL_RATIO * axial + 1e-12
    r0, res = residual(f0)
    steps += res.steps
    best = (abs(r0), f0)
    r1, res = residual(f1)
    steps += res.steps
    for _ in range(max_iterations):
        if abs(r1) < best[0]:
            best = (abs(r1), f1)
        if abs(r1) <= rtol * abs(lateral_stress) or r1 == r0:
            break
        f_new = min(max(f1 - r1 * (f1 - f0) / (r1 - r0), low), high)
        if f_new == f1:          # pinned at a bound: the lateral stress is not reachable within it
            break
        f0, f1, r0 = f1, f_new, r1
        r1, res = residual(f1)
        steps += res.steps
    if abs(r1) > best[0]:
        r1, res = residual(best[1])
        steps += res.steps
    res.steps = steps
    return res
