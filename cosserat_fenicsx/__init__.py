"""Micropolar (Cosserat) continuum on FEniCSx with Gauss-point materials.

Importing the package is light: no Numba, no DEM. Materials that need them
(`cosserat_fenicsx.materials.ehlers`, `demcell`) are imported only by scenes that use them.
"""
from .elasticity import MicropolarElasticity
from .constitutive import Constitutive, ConstitutiveError, LinearElasticMaterial
from .problem import CosseratProblem
from .snes import NewtonSolver
from .stepping import LoadStepper, LoadSteppingError
from . import analytic, cli, meshes

__all__ = ["MicropolarElasticity", "Constitutive", "ConstitutiveError", "LinearElasticMaterial",
           "CosseratProblem", "NewtonSolver", "LoadStepper", "LoadSteppingError"]
__version__ = "0.1.0"
