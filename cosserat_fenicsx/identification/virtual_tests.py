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

The model's answer depends on its load steps (backward Euler of the evolution laws 2.82,
first order: halving the steps halves the error).  A test built for measured data
(:meth:`VirtualTest.following`) ends a step at every data abscissa and splits longer
intervals so that no step exceeds 1/min_steps of the test's range; :meth:`refined` halves
every step, which the identification uses to estimate the discretisation error.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..validation import AXIAL_STRAIN, NON_NEGATIVE, POSITIVE, STEPS, InputError, check

#: the material-point demo's default: 600 steps over a test's range (2.5e-4 axial strain per
#: step over 0.15), each of 1 s; a test following data splits its intervals to at least this
MIN_STEPS = 600

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
    steps of the measured phase; n_consolidation: steps of the consolidation phase.
    path: the abscissa at each step end of the measured phase (axial strain as recorded,
    or pressure [Pa]; the last one the end of the range) with step_times [s] the time of
    each step, instead of n_steps equal steps of 1 s (see :meth:`following`)."""

    kind: str
    confining: float
    axial_strain: float = 0.15
    n_steps: int = 150
    n_consolidation: int = 40
    start_pressure: float = 0.0
    max_cuts: int = 4
    unload_at: float = 0.02
    path: tuple = None
    step_times: tuple = None

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
        if self.path is not None:
            object.__setattr__(self, "path", tuple(float(x) for x in self.path))
            object.__setattr__(self, "step_times", tuple(float(t) for t in self.step_times))
            object.__setattr__(self, "n_steps", len(self.path))
            self.load_path()      # checked here, before any run

    @classmethod
    def following(cls, kind, confining, abscissae, times=None, min_steps=MIN_STEPS, **fields):
        """The test run along data: a step ends at every abscissa of the data (axial strain
        as recorded, or pressure [Pa]), intervals longer than 1/min_steps of the range are
        split into equal steps.  times (same length as abscissae, [s] from the start of the
        measured phase, increasing with the abscissa): the data's time column, which sets
        each step's time (the Perzyna law 2.81 sees the rate); without it a step takes 1 s
        per 1/MIN_STEPS of the range (the material-point demo's default rate)."""
        check(f"{kind} test min_steps", min_steps, STEPS)
        x = np.asarray(abscissae, dtype=float)
        test = cls(kind, confining, **fields)           # the range and its checks
        lo, hi = test.abscissa_range()
        sign = -1.0 if test.abscissa == "axial_strain" and kind not in UNLOADING else 1.0
        start = test.start_pressure if test.abscissa == "pressure" else 0.0
        progress = sign * x if test.abscissa == "axial_strain" else x - start   # >= 0, grows along the test
        span = hi - lo
        if times is None:
            knots = np.unique(progress[progress > 0.0])
            knot_times = None
        else:
            t = np.asarray(times, dtype=float)
            if t.shape != x.shape or not np.all(np.isfinite(t)):
                raise InputError(f"{kind} test: the time column must be finite, one value per data point")
            if np.any(np.diff(progress) <= 0) or np.any(np.diff(t) <= 0):
                raise InputError(f"{kind} test: with a time column the abscissa must progress and the time "
                                 "increase from row to row")
            t0 = t[0] if progress[0] <= 0.0 else 0.0      # a first row at the phase start sets its time
            knots, knot_times = progress[progress > 0.0], t[progress > 0.0] - t0
            if knot_times.size and not knot_times[0] > 0:
                raise InputError(f"{kind} test: the time column must count from the start of the measured phase")
        if knots.size == 0 or knots[-1] < span * (1 - 1e-12):
            if knot_times is not None:    # to the end of the range at the data's mean rate
                rate = knot_times[-1] / knots[-1] if knots.size else MIN_STEPS / span
                knot_times = np.append(knot_times, span * rate)
            knots = np.append(knots, span)
        else:
            knots[-1] = span
        h_max = span / min_steps
        ends, dts, previous, t_prev = [], [], 0.0, 0.0
        for k, b in enumerate(knots):
            # an interval up to 0.1 % longer than h_max is one step: printed data carry their
            # abscissae to a few digits only
            m = max(1, int(np.ceil((b - previous) / h_max - 1e-3)))
            interval = (knot_times[k] - t_prev) if knot_times is not None else (b - previous) * MIN_STEPS / span
            for j in range(1, m + 1):
                ends.append(previous + (b - previous) * j / m if j < m else b)
                dts.append(interval / m)
            previous = b
            if knot_times is not None:
                t_prev = knot_times[k]
        ends = np.asarray(ends)
        path = sign * ends if test.abscissa == "axial_strain" else start + ends
        return dataclasses.replace(test, path=tuple(path), step_times=tuple(dts))

    def refined(self, factor=2):
        """The same test with every step (of both phases) split into `factor` equal steps:
        the difference of the two answers estimates the discretisation error."""
        n_consolidation = self.n_consolidation * factor
        if self.path is None:
            return dataclasses.replace(self, n_steps=self.n_steps * factor, n_consolidation=n_consolidation)
        path, times, previous = [], [], self._phase_start()
        for x, dt in zip(self.path, self.step_times):
            for j in range(1, factor + 1):
                path.append(previous + (x - previous) * j / factor if j < factor else x)
                times.append(dt / factor)
            previous = x
        return dataclasses.replace(self, n_consolidation=n_consolidation, path=tuple(path), step_times=tuple(times))

    def _phase_start(self):
        return self.start_pressure if self.abscissa == "pressure" else 0.0

    def load_path(self):
        """The driver's LoadPath of the measured phase (None: n_steps equal steps)."""
        from ..materials.ehlers.material_point import LoadPath
        if self.path is None:
            return None
        x = np.asarray(self.path)
        if self.step_times is None or len(self.step_times) != x.size:
            raise InputError(f"{self.kind} test: a path needs one step time per step")
        if self.abscissa == "pressure":
            fractions = (x - self.start_pressure) / (self.confining - self.start_pressure)
        elif self.kind in UNLOADING:
            fractions = x / self.axial_strain
        else:
            fractions = x / -self.axial_strain
        try:
            return LoadPath(fractions, self.step_times)
        except InputError as error:
            raise InputError(f"{self.kind} test: {error}") from None

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
        common = dict(point=point, on_record=on_record, stop_on_failure=stop_on_failure, path=self.load_path())
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
