"""A cell loaded as a FEM x DEM Gauss point loads it: the deformation gradient imposed whole.

``strain_path_step`` drives one increment of a biaxial test under full strain control: every
trial goes straight from the committed state to the target F (001 eq. 7), as the macro
Newton's trials do, and the lateral component F[lat, lat] is found by a secant iteration
until the lateral stress is the confining one. The stress servo of ``DemCell.solve`` adjusts
F while the cell relaxes instead; a frictional packing is path dependent, and the two controls
differ by about 1-2 % in the stress ratio before the peak (demos/dem_cell.py
--lateral-control).
"""


def strain_path_step(cell, F, lat, lateral_stress, rtol=1e-4, max_iterations=30):
    """One increment of `cell` (a DemCell) to the 2x2 deformation gradient F, its lateral
    component F[lat, lat] (lat = 0 or 1) found by a secant iteration until the Cauchy stress
    sigma_lat,lat equals `lateral_stress` [N/m] to `rtol` (relative), at most
    `max_iterations` secant updates. The cell is left at the last trial, not committed.
    Returns the last SolveResult, its `steps` the DEM steps of all trials."""
    def residual(f):
        cell.rollback()
        trial = F.copy()
        trial[lat, lat] = f
        cell.set_deformation(trial)
        result = cell.solve()
        return cell.cauchy_stress()[lat, lat] - lateral_stress, result

    steps = 0
    f0 = cell.deformation_gradient()[lat, lat]
    f1 = f0 + 0.3 * abs(F[1 - lat, 1 - lat] - cell.deformation_gradient()[1 - lat, 1 - lat]) + 1e-12
    r0, res = residual(f0)
    steps += res.steps
    r1, res = residual(f1)
    steps += res.steps
    for _ in range(max_iterations):
        if abs(r1) <= rtol * abs(lateral_stress) or r1 == r0:
            break
        f0, f1, r0 = f1, f1 - r1 * (f1 - f0) / (r1 - r0), r1
        r1, res = residual(f1)
        steps += res.steps
    res.steps = steps
    return res
