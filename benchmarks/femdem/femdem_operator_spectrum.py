#!/usr/bin/env python3
"""Why the consistent operator fails past the peak: the spectrum of the cells' operators.

The locked-rotation 1x1 classical biaxial of tests/test_femdem_fallback.py (100-disc cells,
seed 4, steps of 0.1 %), run without the fallback operator: once before the peak (1 %) and
once to 3.6 %, where the PSTLO Newton is refused at every step size. At the last converged
step of each run, per Gauss point, the smallest over the largest eigenvalue of the symmetric
part of the cell's operator d sigma / d eps (sigma11, sigma22, sigma12 against eps11, eps22,
eps12, the Cauchy scene's symmetric strain) for PSTLO and Kruyt: a negative ratio is an
indefinite operator (docs/reference/femdem.md, "Past the peak"). Prints one line per operator
and strain; about a minute.

    python3 benchmarks/femdem/femdem_operator_spectrum.py [--relaxation local|fire]
"""
import argparse

import numpy as np
from mpi4py import MPI

from cosserat_fenicsx.materials.dem import CellOptions
from cosserat_fenicsx.scenes.femdem_biaxial import FemDemBiaxial, FemDemSettings
from cosserat_fenicsx.stepping import LoadSteppingError


def symmetric_ratio(C):
    """min / max eigenvalue of the symmetric part of a cell's 4x4 d sigma / d F (rows and
    columns 11, 12, 21, 22) on the symmetric strain (11, 22, 12; the shear columns summed)."""
    rows, cols = (0, 3, 1), ((0,), (3,), (1, 2))
    S = np.array([[sum(C[r, c] for c in cs) for cs in cols] for r in rows])
    ev = np.linalg.eigvalsh(0.5 * (S + S.T))
    return ev.min() / ev.max()


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--relaxation", choices=("local", "fire"), default="local",
                   help="the cells' relaxation (the figure of the docs: local)")
    a = p.parse_args()
    for strain in (0.010, 0.036):
        settings = FemDemSettings(nx=1, ny=1, mode="classical", axial_strain=strain, steps=round(strain / 1e-3),
                                  fallback_tangent="none",
                                  cell=CellOptions(particles=100, seed=4, rotation=False,
                                                   extra={"method": a.relaxation}))
        test = FemDemBiaxial(MPI.COMM_WORLD, settings, verbose=False)
        try:
            test.run()
        except LoadSteppingError as error:      # the cells are back at the last converged step
            print(f"stopped: {str(error)[:90]}...")
        reached = -test.history[-1]["axial_strain"]
        for kind in ("pstlo", "kruyt"):
            ratios = [symmetric_ratio(cell.tangent(kind)) for cell in test.material.cells]
            print(f"at {100 * reached:.2f} % ({a.relaxation} cells): {kind}: min/max eigenvalue per cell: "
                  f"smallest {min(ratios):.3g}, median {np.median(ratios):.3g}", flush=True)


if __name__ == "__main__":
    main()
