"""The biaxial test of a bounded disc specimen: 004 section 7.4.1 and 000's DNS (section 4.2).

Phase 0 (isotropic stage): every wall servo-controlled to the stress -p, the free sides (if
any) under the confining pressure p, until the walls carry -p and the specimen is at rest
(dns-spec A7); the state there is the origin of displacements and rotations.
Phase 1 (compression): the platens close at a prescribed speed each (004: 0.03 m/s top down
and bottom up), the lateral boundary keeps the confining pressure: membrane + pressure arcs
(004 section 7.3.2), servo-controlled side walls (000's DNS) or a periodic side (fixed period).

``BiaxialTest.row()`` is the specimen's state as one history row (tension positive, strains
relative to the end of phase 0):

    time [s] since the start of phase 1, step, axial_strain (h - h0)/h0, lateral_strain,
    volumetric_strain (A - A0)/A0 (A: the area inside the boundary loop of a membrane
    specimen, the wall rectangle otherwise), axial_stress (mean of the two platens' normal
    stresses, force / loaded width [N/m]), lateral_stress (-p with a membrane, the side walls'
    mean, or the contact stress sigma_xx of a periodic specimen), stress_ratio
    |s_a - s_l| / |s_a + s_l| (000 eq. 40), platen forces [N], coordination, sliding_fraction,
    kinetic_to_elastic, inertial_number, max_overlap.
"""
import math

import numpy as np

from .. import checks
from ..checks import NON_NEGATIVE, POSITIVE
from ..contact_law import ContactLaw
from ..errors import SolveError
from .contacts import contact_geometry
from .engine import Specimen
from .specimens import Discs
from .state import SpecimenOptions, SpecimenState
from .walls import WallControl

#: the servo of the isotropic stage may move the walls at most at the strain rate of this
#: inertial number (I = rate d / sqrt(p / rho), two walls closing): below the quasi-static limit
#: 1e-3, and settling in a few tens of s of simulated time (at the engine's own cap, 1e-4,
#: 000's tiled cell needed some 130 s)
SETTLING_INERTIAL_NUMBER = 8e-4

COLUMNS = ["time", "step", "phase", "axial_strain", "lateral_strain", "volumetric_strain", "axial_stress",
           "lateral_stress", "stress_ratio", "bottom_force", "top_force", "coordination", "sliding_fraction",
           "kinetic_to_elastic", "inertial_number", "max_overlap"]


def polygon_area(points):
    """Shoelace area of a closed polygon (k, 2) [m^2], positive when counter-clockwise."""
    x, y = points[:, 0], points[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def contact_stress(state, area):
    """Mean stress of the contacts over `area` [N/m], tension positive:
    sigma = -(1/A) sum_c f_j (x) d_c (f_j the force on j, d_c = x_j - x_i, minimum image in
    x for a periodic specimen). The wall forces are left out (they act on the platens' rows)."""
    k = np.flatnonzero(state.touching)
    d, _, _, force_j, _, _ = contact_geometry(state.position, state.radius, state.pair_i[k], state.pair_j[k],
                                              state.fn[k], state.fs[k], None, state.period)
    return -np.einsum("ka,kb->ab", force_j, d) / area


class BiaxialTest:
    """Phase 0 and phase 1 of a bounded specimen's biaxial test (module docstring).

    discs: specimens.Discs; law: ContactLaw; options: SpecimenOptions (its lateral kind and
    confining pressure p [N/m] > 0 set the test); platen_speed [m/s]: each platen's speed in
    phase 1 (they close at twice it)."""

    def __init__(self, discs, law, options, platen_speed):
        checks.instance("discs", discs, Discs)
        checks.instance("law", law, ContactLaw)
        checks.instance("options", options, SpecimenOptions)
        checks.number("options.pressure", options.pressure, POSITIVE)
        self.platen_speed = checks.number("platen_speed", platen_speed, POSITIVE)
        state = SpecimenState.from_specimen_discs(discs, lateral=options.lateral)
        self.specimen = Specimen(state, law, options)
        self.pressure = options.pressure
        self.phase = 0
        self.reference = None          # h0, w0, A0 and the time phase 1 started

    @classmethod
    def restored(cls, checkpoint, law, options, platen_speed):
        """The test from a checkpoint written by ``save`` (a dict or an open .npz)."""
        self = cls.__new__(cls)
        self.platen_speed = checks.number("platen_speed", platen_speed, POSITIVE)
        self.specimen = Specimen.restored(checkpoint, law, options)
        self.pressure = options.pressure
        self.phase = int(checkpoint["phase"])
        ref = np.asarray(checkpoint["reference"], float)
        self.reference = None if ref.size == 0 else dict(zip(("height", "width", "area", "time"), ref.tolist()))
        if self.phase == 1:
            self._start_platens()
        return self

    def save(self, path):
        """Everything a restart needs (.npz): the state, the disc order, the phase and the
        reference configuration."""
        ref = [] if self.reference is None else [self.reference[k] for k in ("height", "width", "area", "time")]
        self.specimen.save(path, phase=self.phase, reference=np.array(ref, float))

    @property
    def state(self):
        return self.specimen.state

    # ------------------------------------------------------------------ geometry
    def area(self):
        """Area of the specimen [m^2]: inside the boundary loop's centre polygon plus half a
        disc strip (membrane), or the rectangle of walls / period and platens."""
        st = self.state
        height = float(st.wall_position[1] - st.wall_position[0])
        if self.specimen.options.lateral == "membrane":
            loop = self.specimen.loop
            if loop.size >= 3:
                inner = polygon_area(st.position[loop])
                perimeter = float(np.sum(np.hypot(*np.diff(st.position[np.append(loop, loop[0])], axis=0).T)))
                return inner + 0.5 * perimeter * float(np.mean(st.radius[loop]))
        return self.width() * height

    def width(self):
        """Lateral extent [m]: side walls, period, or the extreme discs of a membrane specimen."""
        return self.specimen.lateral_width()

    # ------------------------------------------------------------------ phases
    def isotropic_stage(self, stress_tolerance=1e-3, energy_tolerance=1e-4, max_time=30.0, max_speed=None):
        """Phase 0 (dns-spec A7): the walls servo to -p until |sigma_w + p| < stress_tolerance p
        and E_kin / E_el < energy_tolerance, at most max_time [s]. The state is then the
        reference of displacements and rotations. Raises SolveError if it does not settle.
        max_speed [m/s] caps the servo (its gain is max_speed / p): None, the wall speed of an
        inertial number of SETTLING_INERTIAL_NUMBER, the quasi-static limit."""
        if max_speed is None:
            st = self.state
            rho = float(np.sum(st.mass) / np.sum(np.pi * st.radius ** 2))
            height = float(st.wall_position[1] - st.wall_position[0])
            max_speed = (0.5 * SETTLING_INERTIAL_NUMBER * height * math.sqrt(self.pressure / rho)
                         / (2.0 * float(np.mean(st.radius))))
        ok, last = self.specimen.isotropic_stage(self.pressure, stress_tolerance=stress_tolerance,
                                                 energy_tolerance=energy_tolerance, max_time=max_time,
                                                 max_speed=max_speed)
        if not ok:
            raise SolveError(f"the isotropic stage did not settle in {max_time:g} s: wall stresses "
                             f"{np.round(last.wall_stress, 4).tolist()} N/m for -{self.pressure:g}, "
                             f"E_kin/E_el = {last.kinetic_energy / max(last.elastic_energy, 1e-300):.2g}")
        self.state.set_reference()
        self.state.velocity[:] = 0.0
        self.state.spin[:] = 0.0
        self.reference = {"height": last.height, "width": self.width(), "area": self.area(), "time": self.state.time}
        return last

    def set_local_damping(self, alpha):
        """Local non-viscous damping alpha in [0, 1) from now on (000 section 3.2.1): phase 0
        may settle with it and phase 1 run without (004) or with it (000's quasi-static DNS)."""
        self.specimen.set_local_damping(alpha)

    def _start_platens(self):
        v = self.platen_speed
        side = None
        if self.specimen.options.lateral == "walls":
            side = WallControl("stress", stress=-self.pressure)
        self.specimen.set_walls(bottom=WallControl("velocity", velocity=v), top=WallControl("velocity", velocity=-v),
                                left=side, right=side)

    def compress(self, until_strain=None, duration=None, on_row=None, every=1):
        """Phase 1: the platens close until the axial strain reaches -until_strain (> 0) or for
        `duration` [s] (one of them); `on_row(row)` every `every` measurements. Returns the
        last row."""
        if self.reference is None:
            raise SolveError("compress needs the isotropic stage first (isotropic_stage)")
        if self.phase == 0:
            self.phase = 1
            self._start_platens()
        if (until_strain is None) == (duration is None):
            raise ValueError("compress needs exactly one of until_strain or duration")
        if duration is None:
            until_strain = checks.number("until_strain", until_strain, POSITIVE)
            h0 = self.reference["height"]
            done = -(self.state.wall_position[1] - self.state.wall_position[0] - h0) / h0
            duration = max(0.0, (until_strain - done) * h0 / (2.0 * self.platen_speed))
        duration = checks.number("duration", duration, NON_NEGATIVE)
        last = {}

        def record(specimen, measurement):
            last["row"] = self.row(measurement)
            if on_row is not None:
                on_row(last["row"])

        self.specimen.run(duration=duration, on_interval=record, every=every)
        return last.get("row")

    def row(self, m):
        """One history row from a Measurement (module docstring)."""
        ref = self.reference
        st = self.state
        width = self.width()
        area = self.area()
        axial = 0.5 * float(m.wall_stress[0] + m.wall_stress[1])
        lateral_kind = self.specimen.options.lateral
        if lateral_kind == "membrane":
            lateral = -self.pressure
        elif lateral_kind == "walls":
            lateral = 0.5 * float(m.wall_stress[2] + m.wall_stress[3])
        else:
            lateral = float(contact_stress(st, area)[0, 0])
        denominator = abs(axial + lateral)
        return {"time": st.time - ref["time"], "step": st.step, "phase": self.phase,
                "axial_strain": (m.height - ref["height"]) / ref["height"],
                "lateral_strain": (width - ref["width"]) / ref["width"],
                "volumetric_strain": (area - ref["area"]) / ref["area"],
                "axial_stress": axial, "lateral_stress": lateral,
                "stress_ratio": abs(axial - lateral) / denominator if denominator > 0 else math.nan,
                "bottom_force": float(m.wall_force[0, 1]), "top_force": float(-m.wall_force[1, 1]),
                "coordination": m.coordination, "sliding_fraction": m.sliding_fraction,
                "kinetic_to_elastic": m.kinetic_energy / m.elastic_energy if m.elastic_energy > 0 else math.nan,
                "inertial_number": m.inertial_number, "max_overlap": m.max_overlap}
