"""Micropolar (Cosserat) continuum on FEniCSx with Gauss-point materials.

Importing the package is light: names are loaded on first use (PEP 562), so the
dolfinx-free parts (`cosserat_fenicsx.materials`, the material-point driver) do not
pull in dolfinx or PETSc, and no scene imports Numba or demcell unless it uses them.
"""
import importlib
import os

# SCOTCH (dolfinx's mesh partitioner in Debian) runs its strategies on several threads by
# default, and then the same mesh on the same ranks is split differently from run to run
# (measured: two partitions of an 18 x 9 mesh on 2 ranks, about one run in two); on one
# thread the partition is the same every time. A user's own setting is kept.
os.environ.setdefault("SCOTCH_PTHREAD_NUMBER", "1")

_EXPORTS = {
    "MicropolarElasticity": "elasticity",
    "Constitutive": "constitutive",
    "ConstitutiveError": "constitutive",
    "LinearElasticMaterial": "constitutive",
    "CosseratProblem": "problem",
    "NewtonSolver": "snes",
    "LoadStepper": "stepping",
    "LoadSteppingError": "stepping",
}
_SUBMODULES = ("analytic", "cli", "compat", "kinematics", "manufactured", "meshes", "output",
               "probes", "quadrature")

__all__ = sorted(_EXPORTS) + list(_SUBMODULES)
__version__ = "0.1.0"


def __getattr__(name):
    if name in _EXPORTS:
        return getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
    if name in _SUBMODULES:
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
