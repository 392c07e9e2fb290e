"""A bounded 2D disc specimen (004 chapter 7, 000 section 4.2): walls, free sides, time loop.

* ``SpecimenState``, ``SpecimenOptions``   state.py   the arrays and the settings
* ``Specimen``, ``Measurement``, ``LostDiscsError``   engine.py   the time loop
* ``WallControl``                          walls.py   prescribed-velocity or servo walls
* ``build_pairs``, ``spatial_order``       contacts.py   cell-list neighbours, pair forces
* the free sides (boundary.py), continuum fields (fields.py), LAMMPS (lammps.py) beside them

Conventions: 2D per unit depth (forces N, stresses N/m), tension positive, x horizontal,
y vertical; walls 0 bottom, 1 top, 2 left, 3 right.
"""
from .state import LATERAL_KINDS, SpecimenOptions, SpecimenState  # noqa: F401
from .walls import WallControl  # noqa: F401
from .contacts import build_pairs, spatial_order  # noqa: F401
from .engine import LostDiscsError, Measurement, Specimen  # noqa: F401
