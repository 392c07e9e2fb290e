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
units, which sets the default internal length of the hybrid mode.
"""
from dataclasses import dataclass, field
import math
import os

import numpy as np

TANGENTS = {"cto": "perturbation", "demqo": "demqo", "kruyt": "kruyt", "pstlo": "pstlo"}


#: DEM steps allowed per cell solve at most (the relaxation kernel counts in int64; a
#: billion steps is days of one cell)
MAX_STEPS = 10 ** 9


@dataclass
class CellOptions:
    """Micro-scale settings (000 Table 3 defaults; pressure as demos/dem_cell.py)."""
    particles: int = 228
    seed: int = 0
    packing: str = None              # .npz written by demos/dem_cell.py (or demcell.save_packing)
    friction: float = 0.4
    pressure: float = 10.0           # p0 [N/m]: compaction and isotropic stage
    kn: float = 1.0e4                # [N/m]
    ks: float = 2.0e3                # [N/m]
    rotation: bool = True            # False: particle rotations locked (000 section 4.3.2)
    relaxation_tol: float = 1e-3     # E_kin/E_pot (energy) or unbalanced-force ratio (force)
    criterion: str = "force"          # 001: max unbalanced force / mean contact force (docs/femdem.md)
    max_steps: int = 200_000         # DEM steps allowed per solve after the loading ramp
    extra: dict = field(default_factory=dict)   # further demcell.RelaxationOptions

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
        check_every = self.relaxation().check_every
        if not (isinstance(self.max_steps, (int, np.integer)) and 2 * check_every <= self.max_steps <= MAX_STEPS):
            raise ValueError(f"max_steps must be an integer in [{2 * check_every}, {MAX_STEPS:.0e}] (the convergence "
                             f"test runs every {check_every} DEM steps), got {self.max_steps!r}")
        if self.packing is not None:
            self.load_packing()      # missing or corrupt: InputError (a ValueError) now
        self.relaxation()            # unknown or bad extra options
        self.law()

    def law(self, friction=None):
        import demcell as dc
        return dc.ContactLaw(kn=self.kn, ks=self.ks, friction=self.friction if friction is None else friction,
                             rotations=self.rotation)

    def relaxation(self):
        import demcell as dc
        return dc.RelaxationOptions.from_kwargs(**dict(dict(tol=self.relaxation_tol, damping=0.7,
                                                            criterion=self.criterion, max_steps=self.max_steps),
                                                       **self.extra))

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
        return dc.generate_packing(self.particles, pressure=self.pressure, law=self.law(), seed=self.seed)


def reference_cells(options, frictions, comm=None):
    """One prepared reference DemCell per zone (zone k: contact friction frictions[k]),
    built on rank 0 and broadcast (the packing generation is seeded, so every rank would
    build the same; doing it once saves the time). Returns (cells, packing info)."""
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
    cells = [dc.DemCell(s, options.law(mu), options.relaxation(), reset_reference=False)
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

