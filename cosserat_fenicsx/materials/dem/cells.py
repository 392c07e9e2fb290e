"""The cell of a FEM x DEM run: options checked before any work, one reference cell per zone.

The options mean what they mean in `demos/dem_cell.py`: the same `particles` and `seed`
give the same packing (demcell.generate_packing with the same contact law), compacted
without friction to `pressure`; a `packing` file (as written by dem_cell.py) replaces the
generation. The reference cell is the packing after the isotropic stage with friction on
(demcell.reference_cell, 000 section 4.1), re-referenced so that F = I and
sigma = -pressure I there: every Gauss point starts from a copy of it, and the macro
specimen starts in equilibrium under the confining pressure.

Units are the cell's (2D, per unit thickness): kn, ks, stresses in N/m. A 2D cell's stress
does not depend on its length unit (forces and branch vectors scale together), so the cell
is placed in the specimen by one length only, the mean grain diameter in the specimen's
units, which sets the default internal length of the hybrid mode. A micropolar cell's
curvature [1/length] and couple stress [N/m x length] do depend on it: the micropolar mode
converts them with length_scale = grain diameter [m] / mean_grain_diameter(cell)
(modes.MicropolarMode).
"""
from dataclasses import dataclass, field
import math
import os

import numpy as np

from ...validation import (DISCS, FRICTION, NON_NEGATIVE, NON_NEGATIVE_INTEGER, POSITIVE, UNIT_OPEN, Range,
                           setting)
from demcell.frame.cell import FRAME_TANGENTS  # noqa: F401 (the tangents a frame cell has)
from demcell.tangent import TANGENT_KINDS

#: the cell operators a DemMaterial's Newton may use, by demcell's names (demcell.tangent's
#: registry: what each computes, micropolar or Cauchy-only, batched, releases the GIL)
TANGENTS = tuple(TANGENT_KINDS)
#: the tangents of Cauchy cells only (the classical and hybrid modes)
CAUCHY_ONLY_TANGENTS = tuple(name for name, kind in TANGENT_KINDS.items() if kind.cauchy_only)
#: the tangents whose per-point work (scipy's sparse LU) releases the GIL, so a rank's
#: threads can share it (materials/dem/stores.py)
GIL_FREE_TANGENTS = tuple(name for name, kind in TANGENT_KINDS.items() if kind.releases_gil)


def check_tangent(tangent, mode):
    """The message refusing `tangent` in the scene mode `mode` ('classical', 'hybrid',
    'micropolar'), or None if the pair is allowed: one rule for the scene's settings and
    for DemMaterial."""
    if tangent not in TANGENTS:
        return f"unknown tangent {tangent!r}: one of {', '.join(TANGENTS)}"
    if mode == "micropolar" and tangent in CAUCHY_ONLY_TANGENTS:
        return (f"tangent {tangent!r} is for Cauchy cells (modes classical and hybrid); mode "
                "'micropolar' has " + ", ".join(t for t in TANGENTS if t not in CAUCHY_ONLY_TANGENTS))
    return None


#: the cell's boundary conditions: periodic images (demcell.DemCell) or paper 000's servo-
#: controlled frame of boundary particles (demcell.frame.FrameCell)
MICRO_BCS = ("periodic", "frame")
#: the cells' relaxation where it differs from demcell.RelaxationOptions' own defaults: FIRE
#: (Bitzek et al. 2006; time step adapted up to fire_dt_max = 2 x the stable one x dt_safety 0.25),
#: damping 0.7 (000 Table 3) for the local damping of `--cell-option method=local`. FIRE reaches
#: the quasi-static answer as closely as local damping does, at about half the DEM steps
#: (benchmarks/femdem/femdem_defaults.py, docs/results/femdem.md "Default cells")
RELAXATION = {"method": "fire", "damping": 0.7}
#: ... and a FIRE relaxation stops 500 DEM steps after its ramp, settled or not
#: (demcell.RelaxationOptions.relax_cap): before the peak the cells settle sooner and the run is the
#: relaxed one bit for bit; past it the cells of a band that fall towards another state are left
#: where 500 steps take them, which keeps the residual a function of the displacement and lets
#: the runs go through their softening (docs/reference/femdem.md, "Past the peak: a cap on the
#: cells' relaxation"). Cells relaxed otherwise (local damping, fixed_steps, frame cells) get no
#: default cap, nor do cells whose step budget (max_steps) is below it: that budget fails a solve
RELAX_CAP = 500
#: ... and of frame cells (micro_bc 'frame'): local damping, as 000 section 3.2.1 (demcell.frame)
FRAME_RELAXATION = {"method": "local", "damping": 0.7}
#: a target initial fabric anisotropy A0 = Phi_1 / Phi_2 - 1 (000 eq. 38)
ANISOTROPY = Range(0.0, 1.0, high_open=True)
#: DEM steps allowed per cell solve at most (the relaxation kernel counts in int64; a
#: billion steps is days of one cell)
MAX_STEPS = 10 ** 9
#: demcell.RelaxationOptions set by a CellOptions field, not through `extra`
OWN_SETTINGS = {"tol": "relaxation_tol (--relaxation-tol)", "criterion": "criterion (--criterion)",
                "max_steps": "max_steps (--max-dem-steps)"}


@dataclass
class CellOptions:
    """Micro-scale settings (000 Table 3 defaults; pressure as demos/dem_cell.py). The fields
    with a help text are demos/femdem_biaxial.py's cell options (cli.add_settings)."""
    particles: int = setting(228, DISCS, "number of discs (000 Table 3)")
    seed: int = setting(0, NON_NEGATIVE_INTEGER, "packing seed")
    anisotropy: float = setting(None, ANISOTROPY,
                                "target initial fabric anisotropy A0 in [0, 1) of the generated packing "
                                "(000 section 4.3.3: 0.02, 0.05, 0.08; deviatoric pre-compaction, "
                                "demcell.generate_packing; default: none, the isotropic compaction's)")
    packing: str = None              # .npz written by demos/dem_cell.py (or demcell.save_packing)
    friction: float = setting(0.4, FRICTION, "Coulomb friction mu (inf: no sliding)")
    pressure: float = setting(10.0, POSITIVE, "confining pressure p0 [N/m] (compaction and isotropic stage)")
    kn: float = setting(1.0e4, POSITIVE, "normal contact stiffness [N/m]")
    ks: float = setting(2.0e3, NON_NEGATIVE, "tangential contact stiffness [N/m]")
    rotation: bool = setting(True, help="particles rotate (--no-rotation: locked, 000 section 4.3.2)")
    relaxation_tol: float = setting(1e-3, UNIT_OPEN, "cell relaxation tolerance of --criterion "
                                    "(001 section 2, 000 Table 3)")
    criterion: str = setting("force", choices=("energy", "force"),
                             help="cell convergence test: unbalanced-force ratio (001) or E_kin/E_pot (000 eq. 31; "
                                  "near the peak it leaves a residual floor above --force-rtol, "
                                  "docs/reference/femdem.md)")
    max_steps: int = setting(200_000, Range(1, MAX_STEPS, integer=True), "DEM steps allowed per cell solve "
                             "after its loading ramp", flag="--max-dem-steps")
    extra: dict = field(default_factory=dict)   # further demcell.RelaxationOptions (over RELAXATION)
    micro_bc: str = setting("periodic", choices=MICRO_BCS,
                            help="the cells' boundary: periodic, or frame (paper 000's frame of boundary particles "
                                 "held by a servo, demcell.frame, cut from the reference cell; "
                                 "docs/reference/frame_cell.md)")
    frame_thickness: float = setting(None, POSITIVE, "frame: width in mean diameters (default: one particle layer)")
    frame_tol: float = setting(1e-3, POSITIVE, "frame: the servo's tolerance eps_a in mean contact forces "
                               "(demcell.frame.FrameOptions)")

    def check(self):
        """Every value in range and the packing file readable, before any cell exists.
        Raises ValueError naming the option."""
        if not (isinstance(self.particles, (int, np.integer)) and self.particles >= 10):
            raise ValueError(f"particles must be an integer >= 10, got {self.particles!r}")
        for name in ("pressure", "kn"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive number, got {v!r}")
        from demcell.packing import check_pressure_ratio
        check_pressure_ratio(self.pressure, self.kn)
        if not (isinstance(self.ks, (int, float)) and math.isfinite(self.ks) and self.ks >= 0):
            raise ValueError(f"ks must be a number >= 0, got {self.ks!r}")
        if not (isinstance(self.friction, (int, float)) and self.friction >= 0 and not math.isnan(self.friction)):
            raise ValueError(f"friction must be >= 0 (inf: no sliding), got {self.friction!r}")
        if not (math.isfinite(self.relaxation_tol) and 0 < self.relaxation_tol < 1):
            raise ValueError(f"relaxation_tol must be in (0, 1), got {self.relaxation_tol!r}")
        if self.criterion not in ("energy", "force"):
            raise ValueError(f"criterion must be 'energy' or 'force', got {self.criterion!r}")
        if not (isinstance(self.seed, (int, np.integer)) and self.seed >= 0):
            raise ValueError(f"seed must be an integer >= 0, got {self.seed!r}")
        if self.anisotropy is not None:
            ANISOTROPY.check("anisotropy (the target A0)", self.anisotropy)
            if self.packing is not None:
                raise ValueError("anisotropy is a target of the generated packing: a packing file has its own")
        check_every = self.relaxation().check_every
        if not (isinstance(self.max_steps, (int, np.integer)) and 2 * check_every <= self.max_steps <= MAX_STEPS):
            raise ValueError(f"max_steps must be an integer in [{2 * check_every}, {MAX_STEPS:.0e}] (the convergence "
                             f"test runs every {check_every} DEM steps), got {self.max_steps!r}")
        if self.micro_bc not in MICRO_BCS:
            raise ValueError(f"micro_bc must be one of {', '.join(MICRO_BCS)}, got {self.micro_bc!r}")
        if self.micro_bc == "frame":
            self.frame_options()     # bad thickness or tolerance: InputError (a ValueError) now
        elif self.frame_thickness is not None:
            raise ValueError("frame_thickness is an option of micro_bc 'frame'")
        if self.packing is not None:
            self.load_packing()      # missing or corrupt: InputError (a ValueError) now
        for name, own in OWN_SETTINGS.items():
            if name in self.extra:
                raise ValueError(f"relaxation option {name!r} has its own setting: {own}")
        self.relaxation()            # unknown or bad extra options
        self.law()

    def frame_options(self):
        """demcell.frame.FrameOptions of the frame cells (micro_bc 'frame')."""
        from demcell.frame import FrameOptions
        return FrameOptions(relaxation=self.relaxation(), thickness=self.frame_thickness, eps_a=self.frame_tol,
                            max_iterations=300)

    def law(self, friction=None):
        import demcell as dc
        return dc.ContactLaw(kn=self.kn, ks=self.ks, friction=self.friction if friction is None else friction,
                             rotations=self.rotation)

    def relaxation(self):
        import demcell as dc
        if self.micro_bc == "frame":
            base = FRAME_RELAXATION
        elif (self.extra.get("method", RELAXATION["method"]) == "fire" and self.extra.get("fixed_steps") is None
              and RELAX_CAP <= self.max_steps):
            base = dict(RELAXATION, relax_cap=RELAX_CAP)
        else:
            base = RELAXATION
        return dc.RelaxationOptions.from_kwargs(**dict(dict(base, tol=self.relaxation_tol, criterion=self.criterion,
                                                            max_steps=self.max_steps), **self.extra))

    def load_packing(self):
        import demcell as dc
        if not os.path.isfile(self.packing):
            raise dc.InputError(f"packing file not found: {self.packing}")
        return dc.load_packing(self.packing)

    def packing_state(self):
        """(state, info) of the compacted packing: from the file, or generated as dem_cell.py does."""
        import demcell as dc
        if self.packing is not None:
            return self.load_packing()
        return dc.generate_packing(self.particles, pressure=self.pressure, law=self.law(), seed=self.seed,
                                   anisotropy=self.anisotropy)


def reference_cells(options, frictions, comm=None, micropolar=False):
    """One prepared reference DemCell per zone (zone k: contact friction frictions[k]),
    built on rank 0 and broadcast (the packing generation is seeded, so every rank would
    build the same; doing it once saves the time). Returns (cells, packing info).

    micropolar: the cells carry rotation and curvature (demcell rotation_mode='micropolar').
    The reference state is prepared as for the other modes (grains free to rotate: the
    isotropic stage of 000 section 4.1) and then wrapped as a micropolar cell without
    re-referencing, so F = I, phi = 0 and kappa = 0 are that prepared state."""
    import demcell as dc
    payload = None
    if comm is None or comm.rank == 0:
        try:
            state, info = options.packing_state()
            states = [dc.reference_cell(state, options.law(mu), options.relaxation(), options.pressure).state
                      for mu in frictions]
            payload = (states, info)
        except Exception as error:   # every rank must hear about it (no MPI hang)
            payload = error
    if comm is not None:
        payload = comm.bcast(payload, root=0)
    if isinstance(payload, Exception):
        raise payload
    states, info = payload
    if micropolar and not options.rotation:
        raise ValueError("mode 'micropolar' needs grains that rotate (not rotation=False / --no-rotation)")
    rotation_mode = "micropolar" if micropolar else None
    if options.micro_bc == "frame":
        if micropolar:
            raise ValueError("micro_bc 'frame' takes no micro-rotation or curvature: mode micropolar needs "
                             "periodic cells")
        from demcell.frame import FrameCell
        return [FrameCell(s, options.law(mu), options.frame_options()) for s, mu in zip(states, frictions)], info
    for s in states:
        if micropolar:      # the imposed values the prepared state is at
            s.phi = 0.0
            s.kappa = np.zeros(2)
    cells = [dc.DemCell(s, options.law(mu), options.relaxation(), reset_reference=False,
                        rotation_mode=rotation_mode)
             for s, mu in zip(states, frictions)]
    return cells, info


def initial_shear_modulus(cell, kind="pstlo"):
    """G = d sigma_12 / d gamma of the cell in pure shear (F12 = F21 = gamma / 2) from its
    tangent at the current state [N/m]: the default mu_c of the hybrid mode."""
    C = cell.tangent(kind)
    return 0.25 * float(C[1, 1] + C[1, 2] + C[2, 1] + C[2, 2])


def mean_grain_diameter(cell):
    """Mean disc diameter of the cell in its own length unit."""
    return 2.0 * float(np.mean(cell.state.radius))


def micropolar_moduli(C, grain_diameter=None):
    """Moduli of a 6x6 micropolar tangent in the Gauss-point order and the specimen's units
    (rows sigma11, sigma22, sigma12, sigma21, m31, m32; columns eps11, eps22, eps12, eps21,
    kappa31, kappa32), read as the isotropic Cosserat law of the hybrid mode (eq. 2.74):

        sigma12 = G (eps12 + eps21) + mu_c (eps12 - eps21),  m = B kappa,  B = 2 mu_c l_c^2

    G = d sym(sigma)_12 / d(eps12 + eps21) and mu_c = d skw(sigma)_12 / d(eps12 - eps21)
    [N/m] (quarter sums of the shear block), B = dm/dkappa [N m] (m in N, kappa in 1/m) the
    mean of the two diagonal bending entries, l_c = sqrt(B / (2 mu_c)) [m] (nan when mu_c <= 0 or
    B < 0). With grain_diameter [m] also l_c / d."""
    C = np.asarray(C, dtype=float)
    S = C[2:4, 2:4]
    G = 0.25 * float(S.sum())
    mu_c = 0.25 * float(S[0, 0] - S[0, 1] - S[1, 0] + S[1, 1])
    B = 0.5 * float(C[4, 4] + C[5, 5])
    l_c = math.sqrt(B / (2.0 * mu_c)) if mu_c > 0.0 and B >= 0.0 else float("nan")
    out = {"G": G, "mu_c": mu_c, "bending_modulus": B, "l_c": l_c,
           "bending_anisotropy": float((C[4, 4] - C[5, 5]) / (C[4, 4] + C[5, 5])) if C[4, 4] + C[5, 5] else 0.0}
    if grain_diameter is not None:
        out["l_c_over_grain_diameter"] = l_c / float(grain_diameter)
    return out
