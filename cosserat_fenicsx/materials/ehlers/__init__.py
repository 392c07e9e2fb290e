"""Micropolar Ehlers elasto-viscoplastic sand model (Scholz 2007), Numba kernels.

Importing this subpackage compiles/loads the Numba kernels; the parent package
``cosserat_fenicsx.materials`` does not import it.
"""

from .errors import MaterialPointError
from .material import EhlersMaterial
from .parameters import EhlersParameters, hostun

__all__ = ["EhlersMaterial", "EhlersParameters", "MaterialPointError", "hostun"]
