"""benchmarks/femdem/femdem_residual_noise.py on a small run before the peak, where the cells'
response is smooth: every re-evaluation repeats bit for bit, the change of the residual grows
in proportion to the perturbation, and the run is the one without the probes.

The strain increment is chosen so that a cell's loading ramp is not a whole number of DEM
steps (at strain_rate 1e-5 an increment of 0.002 is exactly 200 steps): there a perturbation
of any size changes the ramp by one step, and the residual by about 6e-6 of the reactions
(the cells' response has such tolerance-sized jumps by construction)."""
import json
import pathlib
import sys

import numpy as np
import pytest

from benchmarks.femdem import femdem_residual_noise as noise


@pytest.fixture(scope="module")
def probed(tmp_path_factory):
    from mpi4py import MPI
    comm = MPI.COMM_WORLD          # one output folder for every rank: rank 0 writes it
    out = pathlib.Path(comm.bcast(str(tmp_path_factory.mktemp("noise")) if comm.rank == 0 else None))
    argv = sys.argv
    sys.argv = ["femdem_residual_noise.py", "--mesh", "1x1", "--particles", "100", "--axial-strain", "0.00437",
                "--steps", "2", "--out", str(out)]
    try:
        noise.main()
    finally:
        sys.argv = argv
    comm.Barrier()
    with open(out / "residual_noise.json") as f:
        return json.load(f), out


def test_smooth_before_the_peak(probed):
    result, out = probed
    rows = result["rows"]
    assert [r["step"] for r in rows] == [2, 3] and all(r["converged"] for r in rows)
    assert result["stopped"] is None
    for r in rows:
        assert r["deterministic"]
        assert r["reevaluated_ratio"] == r["step_force_ratio"]
        small, large = r["noise"]["1e-09"], r["noise"]["1e-06"]
        assert 0.0 < small < 1e-5
        assert 300.0 < large / small < 3000.0          # linear in the perturbation: a smooth residual
    assert (out / "residual_noise.md").read_text().count("\n| ") == 1 + len(rows)
    assert (out / "residual_noise.png").stat().st_size > 0


def test_probes_leave_the_run_as_it_is(probed, tmp_path):
    """The same run through the scene without the probes: the same Newton iterations and
    force ratios at every step."""
    from mpi4py import MPI
    from cosserat_fenicsx.materials.dem import CellOptions
    from cosserat_fenicsx.scenes.femdem_biaxial import FemDemBiaxial, FemDemSettings
    result, _ = probed
    settings = FemDemSettings(nx=1, ny=1, axial_strain=0.00437, steps=2, cell=CellOptions(particles=100))
    test = FemDemBiaxial(MPI.COMM_WORLD, settings, verbose=False)
    history = test.run()
    plain = {int(row["step"]): row for row in history}
    for r in result["rows"]:
        assert plain[r["step"]]["newton_iterations"] == r["newton_iterations"]
        assert plain[r["step"]]["force_ratio"] == r["step_force_ratio"]
    assert np.isfinite([row["stress_ratio"] for row in history]).all()
