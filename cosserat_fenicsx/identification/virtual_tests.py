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
``triaxial_unloading``     triaxial to eps11 = -unload_at, then    axial_strain (>= 0, from the
                           eps11 increased by axial_strain         unloading start) ->
                           (elastic: step 1(a) of 4.3)             axial_stress_change, volumetric_strain
=========================  ======================================  ===================================

SI units, tension positive (spec section 0): axial strains of a compression test are
negative, the pressure p > 0 is -mean stress; strains are counted from the start of the
deviatoric phase, as the driver's history.csv does.  No dolfinx.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..validation import AXIAL_STRAIN, NON_NEGATIVE, POSITIVE, STEPS, InputError, check

#: kind -> (abscissa, measured quantities)
KINDS = {
    "hydrostatic": ("pressure", ("volumetric_strain",)),
    "isotropic_plane_strain": ("pressure", ("volumetric_strain",)),
    "triaxial": ("axial_strain", ("axial_stress", "volumetric_strain")),
    "biaxial": ("axial_strain", ("axial_stress", "volumetric_strain")),
    "triaxial_unloading": ("axial_strain", ("axial_stress_change", "volumetric_strain")),
}
#: kinds whose abscissa grows from 0 (an unloading branch); the others compress (axial strain <= 0)
UNLOADING = ("triaxial_unloading",)


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
    start_pressure: float = 0.0
    max_cuts: int = 4
    unload_at: float = 0.02

    def __post_init__(self):
        if self.kind not in KINDS:
            raise InputError(f"test kind {self.kind!r} is not one of {sorted(KINDS)}")
        check(f"{self.kind} test confining pressure", self.confining, POSITIVE)
        check(f"{self.kind} test axial strain", self.axial_strain, AXIAL_STRAIN)
        check(f"{self.kind} test n_steps", self.n_steps, STEPS)
        check(f"{self.kind} test n_consolidation", self.n_consolidation, STEPS)
        check(f"{self.kind} test start pressure", self.start_pressure, NON_NEGATIVE)
        check(f"{self.kind} test unload_at", self.unload_at, AXIAL_STRAIN)
        if self.start_pressure > 0 and (self.abscissa != "pressure" or not self.start_pressure < self.confining):
            raise InputError(f"{self.kind} test: a start pressure needs an isotropic test and must be below "
                             f"its final pressure ({self.start_pressure:g} >= {self.confining:g} Pa?)")

    @property
    def abscissa(self):
        return KINDS[self.kind][0]

    @property
    def quantities(self):
        return KINDS[self.kind][1]

    @property
    def counts_from_first_record(self):
        """True when the strains are counted from the state of the first record (deviatoric
        tests, isotropic ones with a start pressure), False when from the unloaded state."""
        return self.abscissa == "axial_strain" or self.start_pressure > 0

    @property
    def label(self):
        if self.kind in UNLOADING:
            return f"{self.kind}_{self.confining / 1e3:g}kPa_at_{100 * self.unload_at:g}%"
        return f"{self.kind}_{self.confining / 1e3:g}kPa"

    def run(self, material, point=None, on_record=None, stop_on_failure=False):
        """Run the test on `material` (an EhlersMaterial); returns the driver's history
        dict (arrays per record) with a "pressure" entry (-mean stress) added.  point: a
        fresh MaterialPoint (subclass) to drive, e.g. one that carries sensitivities."""
        from ..materials.ehlers import material_point as mp
        if point is None:
            point = mp.MaterialPoint(material)
        point.max_cuts = self.max_cuts
        common = dict(point=point, on_record=on_record, stop_on_failure=stop_on_failure)
        if self.abscissa == "pressure":
            run = mp.hydrostatic_test if self.kind == "hydrostatic" else mp.isotropic_plane_strain_test
            h = run(material, self.confining, n_steps=self.n_steps, p_start=self.start_pressure,
                    n_consolidation=self.n_consolidation, **common)
        elif self.kind == "triaxial_unloading":
            h = mp.unloading_test(material, self.confining, self.unload_at, self.axial_strain, self.n_steps,
                                  self.n_consolidation, **common)
        else:
            run = mp.triaxial_test if self.kind == "triaxial" else mp.biaxial_test
            h = run(material, self.confining, self.axial_strain, self.n_steps, self.n_consolidation, **common)
        h["pressure"] = self.pressure(h)
        return self.derive(h)

    def derive(self, h, dh=None):
        """Add the quantities computed from the records, to h and (when given) to its
        sensitivities dh: an unloading branch measures the axial stress *change* from its
        start, which the plasticity before the unloading does not set."""
        if self.kind in UNLOADING:
            a = np.asarray(h["axial_stress"])
            h["axial_stress_change"] = a - a[0]
            if dh is not None:
                dh["axial_stress_change"] = dh["axial_stress"] - dh["axial_stress"][0]
        return h

    def pressure(self, h):
        """The pressure of the test's records: -tr(sigma)/3, or in plane strain the in-plane
        -(sig11 + sig22)/2 that a 2D cell reports (sig33 is not measured there)."""
        if self.kind == "isotropic_plane_strain":
            return np.asarray(h["in_plane_pressure"])
        return -np.asarray(h["mean_stress"])

    def abscissa_range(self):
        """(lo, hi) of the abscissa the test covers: data outside it cannot be compared."""
        if self.abscissa == "pressure":
            return self.start_pressure, self.confining
        if self.kind in UNLOADING:
            return 0.0, self.axial_strain
        return -self.axial_strain, 0.0
