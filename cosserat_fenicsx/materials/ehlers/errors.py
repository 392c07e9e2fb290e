"""Errors raised by the Ehlers Gauss-point update (no Numba import here)."""

from ...constitutive import ConstitutiveError


class MaterialPointError(ConstitutiveError):
    """The local (Gauss-point) problem has no acceptable solution.

    A ConstitutiveError, so the FE load stepper turns it into a cut-back.
    Raised instead of ever returning NaN.  The message names the cause and the
    index of the first failing point; ``codes`` holds the per-point status
    array (0 = ok, see :data:`STATUS_MESSAGES`) so the caller (the FE Newton)
    can decide to cut the load step back.
    """

    def __init__(self, message, codes=None, point=None):
        super().__init__(message)
        self.codes = codes
        self.point = point


#: Status codes written by the Numba kernel, one per point.
STATUS_OK = 0
STATUS_NOT_CONVERGED = 1
STATUS_COMPRESSION_POINT = 2
STATUS_TENSILE = 3
STATUS_NONFINITE_INPUT = 4
STATUS_SINGULAR = 5

STATUS_MESSAGES = {
    STATUS_NOT_CONVERGED: "local Newton did not converge (after substepping the strain increment)",
    STATUS_COMPRESSION_POINT: ("volumetric elastic strain reached the compression point eps_crit "
                               "(eq. 2.70: no elastic state with n^S < n_max^S); reduce the load increment"),
    STATUS_TENSILE: ("tensile state: no admissible stress (frictional material has no tensile "
                     "strength, F > 0 for every I_sigma > 0, eq. 2.76)"),
    STATUS_NONFINITE_INPUT: "non-finite strain, curvature or history on input",
    STATUS_SINGULAR: "singular local Jacobian (Table 3.1 system) at the stress apex or in a degenerate state",
}
