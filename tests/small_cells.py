"""A small cell shared by the tests of solves that stop early (fixed_steps, relax_cap): 40
discs at 10 N/m, relaxed to an unbalanced-force ratio of 1e-3; a copy with other relaxation
options; the biaxial F of a strain e."""
import dataclasses

import numpy as np

import demcell as dc

LAW = dc.ContactLaw(kn=1e4, ks=2e3, friction=0.4)


def cell40():
    state, _ = dc.generate_packing(40, pressure=10.0, law=LAW, seed=2)
    return dc.reference_cell(state, LAW, dc.RelaxationOptions(tol=1e-3, criterion="force"), 10.0)


def with_options(cell, **changes):
    """A copy of `cell` whose RelaxationOptions have `changes`."""
    out = cell.copy()
    out.options = dataclasses.replace(cell.options, **changes)
    return out


def biaxial(e):
    """F of a biaxial strain: -e along y, e / 2 along x."""
    return np.array([[1 + 0.5 * e, 0.0], [0.0, 1 - e]])
