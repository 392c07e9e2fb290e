"""demcell: a Numba periodic 2D DEM cell answering "what stress for this deformation?".

The micro-scale half of FEM x DEM (papers 000, 001 in ../shared/seeds). No dolfinx import.
Main entry points:

* ``ContactLaw``                      contact_law.py   (000 eq. 10, 003 Table 1)
* ``generate_packing``, ``hexagonal_lattice``   packing.py
* ``save_packing``, ``load_packing``, ``write_vtk_snapshot``   io.py
* ``MicroCell`` (interface), ``DemCell``, ``create_cells``, ``RelaxationOptions``  interface.py
* ``isotropic_stage``, ``reference_cell``   preparation.py (000 section 4.1)
* ``homogenize`` / ``Homogenized``    homogenization.py (000 eqs. 14, 16, 38-40; 001 eq. 8)
* tangents                             tangent.py (001 eqs. 6, 13, 20)
* micropolar cell: ``DemCell(..., rotation_mode="micropolar")`` takes a micro-rotation and a
  curvature (docs/reference/micropolar_cell.md); its frozen contact network solved exactly and the
  uniform-field operator in network.py; closed forms and paper 003's moduli in estimates.py

Conventions: tension positive, (Grad u)_ij = du_i/dX_j, t_i = sigma_ij n_j, 2D quantities
per unit thickness (stress in N/m). See docs/reference/demcell.md.
"""
import os as _os

from .numba_cache import clear_stale_cache as _clear_stale_cache

_clear_stale_cache(_os.path.dirname(_os.path.abspath(__file__)))   # before any kernel loads

from .contact_law import ContactLaw  # noqa: E402
from .errors import DemCellError, InputError, SolveError  # noqa: E402
from .homogenization import Homogenized, homogenize  # noqa: E402
from .interface import ROTATION_MODES, DemCell, MicroCell, RelaxationOptions, SolveResult, create_cells  # noqa: E402
from .io import load_packing, save_packing, write_vtk_snapshot  # noqa: E402
from .packing import generate_packing, hexagonal_lattice, loose_state  # noqa: E402
from .preparation import isotropic_stage, reference_cell  # noqa: E402
from .state import CellState  # noqa: E402

__all__ = ["ContactLaw", "DemCellError", "InputError", "SolveError", "Homogenized", "homogenize",
           "DemCell", "ROTATION_MODES", "MicroCell", "RelaxationOptions", "SolveResult", "create_cells",
           "load_packing", "save_packing", "write_vtk_snapshot", "generate_packing",
           "hexagonal_lattice", "loose_state", "CellState", "isotropic_stage", "reference_cell"]
