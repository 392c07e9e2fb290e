"""The homogeneous tests an identification simulates (thesis section 4.3, Table 4.2, A.1, A.2).

A :class:`VirtualTest` names one laboratory test and how the material-point driver
(`materials/ehlers/material_point.py`, no mesh) runs it:

=========================  ======================================  ===================================
kind                       loading                                 measured (abscissa -> quantities)
=========================  ======================================  ===================================
``hydrostatic``            sig11 = sig22 = sig33 = -p to p_max      pressure -> volumetric_strain
``isotropic_plane_strain`` sig11 = sig22 = -p, eps33 = 0           pressure -> volumetric_strain
``triaxial``               consolidation to -p, eps11 decreased    axial_strain -> axial_stress,
                           at sig22 = sig33 = -p                   volumetric_strain
``biaxial``                plane strain (eps33 = 0), consolidation axial_strain -> axial_stress,
                           to -p, eps11 decreased at sig22 = -p    volumetric_strain
=========================  ======================================  ===================================

SI units, tension positive (spec section 0): axial strains of a compression test are
negative, the pressure p > 0 is -mean stress; strains are counted from the start of the
deviatoric phase, as the driver's history.csv does.  No dolfinx.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..validation import AXIAL_STRAIN, POSITIVE, STEPS, InputError, check

#: kind -> (abscissa, measured quantities)
KINDS = {
    "hydrostatic": ("pressure", ("volumetric_strain",)),
    "isotropic_plane_strain": ("pressure", ("volumetric_strain",)),
    "triaxial": ("axial_strain", ("axial_stress", "volumetric_strain")),
    "biaxial": ("axial_strain", ("axial_stress", "volumetric_strain")),
}


@dataclasses.dataclass(frozen=True)
class VirtualTest:
    """One homogeneous test.  confining [Pa]: the cell pressure of a triaxial/biaxial test,
    or the final pressure p_max of a hydrostatic/isotropic one; axial_strain: magnitude of
    the axial compression of the deviatoric phase (deviatoric kinds only); n_steps: load
    steps of the measured phase; n_consolidation: steps of the consolidation phase."""

    kind: str
    confining: float
    axial_strain: float = 0.15
    n_steps: int = 150
    n_consolidation: int = 40

    def __post_init__(self):
        if self.kind not in KINDS:
            raise InputError(f"test kind {self.kind!r} is not one of {sorted(KINDS)}")
        check(f"{self.kind} test confining pressure", self.confining, POSITIVE)
        check(f"{self.kind} test axial strain", self.axial_strain, AXIAL_STRAIN)
        check(f"{self.kind} test n_steps", self.n_steps, STEPS)
        check(f"{self.kind} test n_consolidation", self.n_consolidation, STEPS)

    @property
    def abscissa(self):
        return KINDS[self.kind][0]

    @property
    def quantities(self):
        return KINDS[self.kind][1]

    @property
    def label(self):
        return f"{self.kind}_{self.confining / 1e3:g}kPa"

    def run(self, material, point=None, on_record=None, stop_on_failure=False):
        """Run the test on `material` (an EhlersMaterial); returns the driver's history
        dict (arrays per record) with a "pressure" entry (-mean stress) added.  point: a
        fresh MaterialPoint (subclass) to drive, e.g. one that carries sensitivities."""
        from ..materials.ehlers import material_point as mp
        common = dict(point=point, on_record=on_record, stop_on_failure=stop_on_failure)
        if self.kind == "hydrostatic":
            h = mp.hydrostatic_test(material, self.confining, n_steps=self.n_steps, **common)
        elif self.kind == "isotropic_plane_strain":
            h = mp.isotropic_plane_strain_test(material, self.confining, n_steps=self.n_steps, **common)
        else:
            run = mp.triaxial_test if self.kind == "triaxial" else mp.biaxial_test
            h = run(material, self.confining, self.axial_strain, self.n_steps, self.n_consolidation, **common)
        h["pressure"] = -np.asarray(h["mean_stress"])
        return h

    def abscissa_range(self):
        """(lo, hi) of the abscissa the test covers: data outside it cannot be compared."""
        if self.abscissa == "pressure":
            return 0.0, self.confining
        return -self.axial_strain, 0.0
