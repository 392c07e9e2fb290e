"""FEM x DEM: a demcell periodic DEM cell at every Gauss point (docs/reference/femdem.md).

The only part of cosserat_fenicsx that imports demcell; importing this subpackage loads
demcell's Numba kernels, the parent package `cosserat_fenicsx.materials` does not.
"""
from .cells import CAUCHY_ONLY_TANGENTS, GIL_FREE_TANGENTS, TANGENTS, CellOptions, check_tangent, initial_shear_modulus, mean_grain_diameter, reference_cells
from .material import DemMaterial
from .modes import MODES, ClassicalMode, HybridMode, MicropolarMode, make_mode

__all__ = ["TANGENTS", "CAUCHY_ONLY_TANGENTS", "GIL_FREE_TANGENTS", "check_tangent", "MODES", "CellOptions", "DemMaterial", "ClassicalMode", "HybridMode",
           "MicropolarMode", "make_mode", "reference_cells", "initial_shear_modulus", "mean_grain_diameter"]
