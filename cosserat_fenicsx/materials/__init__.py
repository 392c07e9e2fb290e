"""Constitutive models evaluated at quadrature points.

This package must stay import-light: importing it (or any elastic FE scene)
must never import Numba.  The Numba-compiled Ehlers kernels live in
:mod:`cosserat_fenicsx.materials.ehlers` and are only imported when that
subpackage is used explicitly, e.g.::

    from cosserat_fenicsx.materials.ehlers import EhlersMaterial

The FEM x DEM material (a demcell cell per Gauss point) is :mod:`cosserat_fenicsx.materials.dem`,
the only subpackage that imports demcell.
"""

__all__ = ["ehlers", "dem"]
