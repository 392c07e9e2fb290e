"""Full-DEM strip footing (003 section 3): the reference solution of the bridging-scale method.

The whole domain (003: 18 m x 9 m, plane strain, per metre of depth) is filled with discs of
003's packing A, B or C (specimens.rotated_square_lattice, specimens.random_dense), held by
fixed smooth walls at the bottom and the sides (003 gives no outer conditions; 003-bsm.md
section 8 [R]: u_x = u_y = 0 at the bottom, u_x = 0 at the sides). A rigid plate 2 m wide at
the top centre (plate.Plate) is pushed down at 1 m/s to a settlement of 60 mm (0.06 s); the
load is the plate's vertical reaction [N per m of depth]. No gravity by default (003 mentions
none); with gravity g the specimen first settles under its weight (``settle``: local damping,
the plate clear of the surface), then the plate is put on the settled surface and pushed. The
top wall of the specimen engine is lifted out of reach: the surface is free.

Contact law, 003 Table 1 (2D, per unit depth): k_N = 2.5e8 N/m, k_s = 5e7 N/m, mu_s = 0.5,
rolling k_omega = 700 N m/rad with the limit mu_omega f_N, mu_omega = 0.5e-3 m, that is
eta_r = mu_omega / R_eff in demcell's law, R_eff = r_mean / 2 (exact for the equal discs of
A and B; for C the mean radius is used, so the limit is right only on average). The
dashpots of Table 1 (c = 0.4 N s/m, damping ratio ~ 4e-6) are negligible and left out. Li
and Chu's rolling force (k_r = 1e6 N/m, mu_r = 0.05) has no counterpart in demcell: it is
missing. Discs of 2600 kg/m^3 per metre of depth (Table 1's "N/m^3" read as kg/m^3).

Time step: dt = fraction sqrt(m_min / k_N) (003-bsm.md section 4: 2.9e-4 s for r = 0.05 m,
1.1e-4 s for r = 0.02 m; default fraction 0.1), checked against the engine's stability
limit (engine.check_time_step). Mass damping c_m (003 eqs. 9, 29) on every disc; 003 gives
no value. It also resists the motion of the discs carried down with the plate: about c_m
rho v times the area moving with it, a bias of the quasi-static load to keep in mind.
"""
import contextlib
import math
import os
import time
from dataclasses import dataclass, field

import numpy as np

from .. import checks
from ..checks import NON_NEGATIVE, POSITIVE, Range
from ..contact_law import ContactLaw
from ..errors import InputError
from .engine import Specimen, check_time_step
from .plate import Plate
from .specimens import rotated_square_lattice, random_dense
from .state import SpecimenOptions, SpecimenState

#: 003 Table 1
KN, KS, MU, K_OMEGA, MU_OMEGA, DENSITY = 2.5e8, 5.0e7, 0.5, 700.0, 0.5e-3, 2600.0
#: 003 section 3 packings: A and B equal radii [m], C a uniform range [m]
PACKINGS = {"A": (0.05, 0.05), "B": (0.03, 0.03), "C": (0.02, 0.05)}
#: height above the domain [m] at which the engine's (unused) top wall is parked
TOP_WALL_CLEARANCE = 1.0
#: settling under gravity: local damping alpha [-] and duration [s] (the lattice A settles
#: within about 0.2 s, docs/results/bsm.md)
SETTLE_DAMPING, SETTLE_TIME = 0.7, 0.3


def table1_law(mean_radius):
    """003 Table 1 as a demcell ContactLaw for discs of mean radius r [m] (module docstring:
    eta_r = mu_omega / (r / 2); no dashpots; no rolling force)."""
    mean_radius = checks.number("mean_radius", mean_radius, POSITIVE)
    return ContactLaw(kn=KN, ks=KS, friction=MU, rolling_stiffness=K_OMEGA,
                      rolling_friction=MU_OMEGA / (0.5 * mean_radius))


def footing_packing(packing, box, seed=0, n_cell=600):
    """Discs of 003's packing "A", "B" or "C" filling box (x_min, x_max, y_min, y_max) [m]."""
    checks.choice("packing", packing, tuple(PACKINGS))
    r0, r1 = PACKINGS[packing]
    if packing in ("A", "B"):
        return rotated_square_lattice(box, r0, DENSITY)
    return random_dense(box, r0, r1, DENSITY, n_cell=n_cell, seed=seed, law=table1_law(0.5 * (r0 + r1)))


@dataclass
class FootingResult:
    """Force-settlement history of a footing run and its cost.

    settlement (k,) [m] (positive down), load (k,) [N/m] (the plate's vertical reaction,
    positive when the plate pushes the discs down), time (k,) [s]; wall_seconds, cpu_seconds:
    the loading loop (process CPU time, all threads); specimen: the engine at the end (its
    ``state`` is the final state); info: the scene's numbers."""
    settlement: np.ndarray
    load: np.ndarray
    time: np.ndarray
    wall_seconds: float
    cpu_seconds: float
    specimen: Specimen
    info: dict = field(default_factory=dict)

    def peak(self):
        """(largest load [N/m], settlement at it [m])."""
        k = int(np.argmax(self.load))
        return float(self.load[k]), float(self.settlement[k])


def plate_on_surface(spec, x0, x1, rough=False):
    """Put a rigid plate over [x0, x1] [m] on the highest disc under it, at rest; returns its
    height [m]."""
    p, r = spec.state.position, spec.state.radius
    under = (p[:, 0] + r > x0) & (p[:, 0] - r < x1)
    if not np.any(under):
        raise InputError("no disc lies under the plate")
    top = float(np.max(p[under, 1] + r[under]))
    spec.set_plate(Plate(x0, x1, top, (0.0, 0.0), rough=rough))
    return top


@contextlib.contextmanager
def settling(spec, local_damping=SETTLE_DAMPING):
    """Within the block the specimen's discs are damped for settling: local damping alpha and
    no mass damping (mass damping leaves the contacts' own vibrations of a lattice ringing);
    its damping is restored on leaving. For a caller that steps the specimen itself (the
    bridging coupler); ``settle`` steps it here."""
    local_damping = checks.number("settle local damping", local_damping, Range(0.0, 1.0, low_open=True,
                                                                               high_open=True))
    alpha, c_m = spec.options.local_damping, spec.options.mass_damping
    spec.set_local_damping(local_damping)
    spec.set_mass_damping(0.0)
    try:
        yield spec
    finally:
        spec.set_local_damping(alpha)
        spec.set_mass_damping(c_m)


def settle(spec, duration=SETTLE_TIME, local_damping=SETTLE_DAMPING):
    """Let the specimen settle under its gravity for `duration` [s] (``settling``'s damping).
    Returns {"settle_time", "settle_steps", "settle_kinetic_energy" [J/m] (Specimen.measure's,
    rotations included), "settle_max_speed" [m/s] of a free disc} at the end."""
    duration = checks.number("settle duration", duration, POSITIVE)
    steps = max(1, int(round(duration / spec.options.dt)))
    with settling(spec, local_damping):
        spec.advance(steps)
    speed = np.hypot(spec.state.velocity[:, 0], spec.state.velocity[:, 1])[~spec.held]
    return {"settle_time": steps * spec.options.dt, "settle_steps": steps,
            "settle_kinetic_energy": spec.measure().kinetic_energy, "settle_max_speed": float(speed.max(initial=0.0))}


def footing_specimen(packing="A", width=18.0, height=9.0, plate_width=2.0, rough=False, mass_damping=10.0,
                     dt_fraction=0.1, seed=0, n_cell=600, discs=None, threads=None, lateral="walls", gravity=0.0):
    """The footing scene at rest, before loading: (Specimen with its plate, info dict).

    width x height [m]: the domain (003: 18 x 9), filled with `packing` (or the given
    specimens.Discs `discs`); plate_width [m] centred on the top; rough: plate friction mu_s
    (False: smooth); mass_damping c_m [1/s]; dt = dt_fraction sqrt(m_min / k_N);
    lateral "walls" (fixed walls bottom and sides) or "none" (no wall: the caller holds
    discs); gravity g [m/s^2] (>= 0) downwards (the scene is not settled here: ``settle``).
    Under gravity the side and bottom walls are put against the packing's outermost discs
    (the lattices A and B end a fraction of a spacing short of the right face: under their
    weight they would slump sideways into that gap, tilting the surface; weightless the gap
    is harmless and the walls stay on the domain's faces)."""
    width = checks.number("width", width, POSITIVE)
    height = checks.number("height", height, POSITIVE)
    plate_width = checks.number("plate_width", plate_width, Range(0.0, width, low_open=True))
    mass_damping = checks.number("mass_damping", mass_damping, NON_NEGATIVE)
    dt_fraction = checks.number("dt_fraction", dt_fraction, Range(0.0, 1.0, low_open=True))
    checks.choice("lateral", lateral, ("walls", "none"))
    gravity = checks.number("gravity", gravity, NON_NEGATIVE)
    given = discs is not None
    if not given:
        discs = footing_packing(packing, (0.0, width, 0.0, height), seed=seed, n_cell=n_cell)
    law = table1_law(float(np.mean(discs.radius)))
    dt = dt_fraction * math.sqrt(float(np.min(discs.mass)) / KN)
    check_time_step(dt, discs.mass, KN)
    box = (0.0, width, 0.0, height + TOP_WALL_CLEARANCE)
    if gravity > 0.0 and lateral == "walls":
        p, r = discs.position, discs.radius
        box = (float(np.min(p[:, 0] - r)), float(np.max(p[:, 0] + r)), float(np.min(p[:, 1] - r)),
               height + TOP_WALL_CLEARANCE)
    state = SpecimenState.from_discs(discs.position, discs.radius, discs.mass, discs.inertia, box, lateral=lateral)
    options = SpecimenOptions(dt=dt, mass_damping=mass_damping, lateral=lateral, threads=threads,
                              normal_dashpot=0.0, tangential_dashpot=0.0, gravity=(0.0, -gravity))
    spec = Specimen(state, law, options)
    x0 = 0.5 * (width - plate_width)
    x1 = x0 + plate_width
    top = plate_on_surface(spec, x0, x1, rough)
    r = discs.radius
    info = {"gravity": gravity, "walls": list(box[:3]), "packing": "given" if given else packing,
            "n_discs": int(discs.n_discs), "width": width, "height": height, "plate_width": plate_width,
            "plate_x": [x0, x1], "plate_y0": top, "rough": bool(rough), "mass_damping": mass_damping, "dt": dt,
            "dt_fraction": dt_fraction, "solid_fraction": discs.solid_fraction(),
            "r_min": float(np.min(r)), "r_max": float(np.max(r)), "law": law.to_dict(), "packing_info": discs.info,
            "lateral": lateral}
    return spec, info


def run_footing(packing="A", width=18.0, height=9.0, plate_width=2.0, speed=1.0, depth=0.06, rough=False,
                mass_damping=10.0, dt_fraction=0.1, record_every=1, seed=0, n_cell=600, discs=None, threads=None,
                on_record=None, gravity=0.0, settle_time=SETTLE_TIME):
    """The footing (``footing_specimen``) loaded: the plate goes down at `speed` [m/s] to the
    settlement `depth` [m]; every `record_every` steps the settlement and the load are
    recorded (the load of the last step: no averaging). on_record(dict) is called at each
    record if given, with the settlement [m], load [N/m], time [s], step count and the
    engine itself ("specimen": read its state, e.g. grain positions, do not advance it).
    With gravity g > 0 [m/s^2] the specimen first settles for settle_time [s] (``settle``) and
    the plate is put on the settled surface; the settlement counts from there and the time
    from the start of the loading. Returns a FootingResult."""
    speed = checks.number("speed", speed, POSITIVE)
    depth = checks.number("depth", depth, POSITIVE)
    record_every = checks.number("record_every", record_every, Range(1, integer=True))
    spec, info = footing_specimen(packing, width, height, plate_width, rough, mass_damping, dt_fraction, seed,
                                  n_cell, discs, threads, gravity=gravity)
    if gravity > 0.0:
        c0, w0 = time.process_time(), time.perf_counter()
        info.update(settle(spec, settle_time))
        x0, x1 = info["plate_x"]
        info["plate_y0"] = plate_on_surface(spec, x0, x1, rough)
        info.update(settle_cpu_seconds=time.process_time() - c0, settle_wall_seconds=time.perf_counter() - w0)
    dt = spec.options.dt
    n_steps = max(1, int(round(depth / (speed * dt))))
    spec.set_plate_velocity(0.0, -speed)
    y0 = spec.plate_position()[2]
    t_start = spec.state.time
    settlement, load, times = [0.0], [0.0], [0.0]
    spec.load_kernels()          # the loop's times are the stepping's
    c0, w0 = time.process_time(), time.perf_counter()
    done = 0
    while done < n_steps:
        k = min(record_every, n_steps - done)
        spec.advance(k)
        done += k
        settlement.append(y0 - spec.plate_position()[2])
        load.append(-float(spec.plate_reaction()[1]))
        times.append(spec.state.time - t_start)
        if on_record is not None:
            on_record({"settlement": settlement[-1], "load": load[-1], "time": times[-1], "step": done,
                       "specimen": spec})
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    info.update(speed=speed, depth=depth, n_steps=n_steps, record_every=record_every, rebuilds=spec.rebuilds,
                kernel_wall_seconds=spec.wall_seconds, kernel_cpu_seconds=spec.cpu_seconds,
                threads=int(__import__("numba").get_num_threads()), cpu_count=os.cpu_count())
    return FootingResult(np.array(settlement), np.array(load), np.array(times), wall, cpu, spec, info)


__all__ = ["table1_law", "footing_packing", "footing_specimen", "run_footing", "settle", "settling", "plate_on_surface",
           "FootingResult", "PACKINGS", "SETTLE_TIME", "SETTLE_DAMPING",
           "KN", "KS", "MU", "K_OMEGA", "MU_OMEGA", "DENSITY"]
