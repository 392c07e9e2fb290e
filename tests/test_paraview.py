"""The XDMF output opens in ParaView itself: field names and ranges, and a rendered PNG."""
import json
import os
import shutil
import subprocess
import time

import numpy as np
import pytest

from conftest import ROOT

pytestmark = [pytest.mark.serial,
              pytest.mark.skipif(shutil.which("pvbatch") is None or shutil.which("xvfb-run") is None,
                                 reason="ParaView (python3-paraview) or xvfb-run not installed")]


def pvbatch_json(script, *args, attempts=10):
    """Run `xvfb-run -a pvbatch script args` and return the JSON it prints. pvbatch is retried,
    after a pause that grows by a second each time, when it aborts because it could not open the
    X display ("bad X server connection"): on a loaded machine XOpenDisplay against a running
    Xvfb fails now and then (measured here: 3 to 5 of 12 runs beside a 2-rank run, load
    average 2-3; four tries in a row failed once in a `make test` beside one), which says
    nothing about our files. Any other failure is reported as is."""
    for attempt in range(attempts):
        if attempt:
            time.sleep(attempt)
        proc = subprocess.run(["xvfb-run", "-a", "pvbatch", str(script), *map(str, args)],
                              capture_output=True, text=True, timeout=300)
        lines = [l for l in proc.stdout.splitlines() if l.startswith("PARAVIEW_JSON ")]
        if lines or "bad X server connection" not in proc.stderr:
            break
    assert lines, f"pvbatch failed ({proc.returncode}):\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}"
    return json.loads(lines[-1][len("PARAVIEW_JSON "):])


def paraview_read(xdmf, png, colour_by):
    return pvbatch_json(os.path.join(ROOT, "tests", "paraview_check.py"), xdmf, png, colour_by)


def test_shear_layer_fields_in_paraview(demo, tmp_path):
    shift = 1.0e-3
    demo("shear_layer", "--steps", 2, "--shift", shift, "--out", tmp_path)
    data = paraview_read(tmp_path / "fields.xdmf", tmp_path / "render.png", "rotation")
    arrays = data["arrays"]
    assert {"displacement", "rotation", "stress", "couple_stress"} <= set(arrays)
    assert data["times"] == pytest.approx([0.5, 1.0])
    # u1 runs from 0 (bottom) to the imposed shift (top); u2 = 0
    assert arrays["displacement"]["range"][0] == pytest.approx([0.0, shift], abs=1e-6 * shift)
    assert np.abs(arrays["displacement"]["range"][1]).max() < 1e-3 * shift
    # rotation range equals the profile's (sampled along the mid-line)
    profile = np.genfromtxt(tmp_path / "profile.csv", delimiter=",", names=True)
    phi_min, phi_max = arrays["rotation"]["range"][0]
    assert phi_min == pytest.approx(profile["phi"].min(), rel=0.02)
    assert phi_max == pytest.approx(0.0, abs=1e-9)
    # the stress tensor is cell data, shear component near the closed-form tau
    tau = json.load(open(tmp_path / "summary.json"))["shear_stress_exact"]
    assert arrays["stress"]["kind"] == "cell"
    assert max(abs(v) for v in arrays["stress"]["range"][1]) == pytest.approx(tau, rel=0.05)
    # the render really shows the field: the boundary layers give many colours along
    # the vertical centre line (a blank or solid-colour render gives one or two)
    import matplotlib.image
    image = matplotlib.image.imread(str(tmp_path / "render.png"))
    column = image[:, image.shape[1] // 2, :3].reshape(-1, 3)
    assert len({tuple(np.round(c, 2)) for c in column}) > 20


def test_only_requested_fields_are_written(demo, tmp_path):
    demo("shear_layer", "--fields", "displacement", "--out", tmp_path)
    data = paraview_read(tmp_path / "fields.xdmf", tmp_path / "render.png", "displacement")
    assert set(data["arrays"]) == {"displacement"}


def test_footing_continuum_and_grains_open_together(demo, tmp_path):
    """demos/footing_bsm.py's ParaView state opens continuum.xdmf and grains.vtk.series on one
    clock: the same time steps (the run's seconds), every grain, the coarse/fine arrays; a
    restarted run's state opens the continued series."""
    demo("footing_bsm", "--packing", "A", "--depth", 0.004, "--record-every", 4, "--output-every", 2,
         "--stop-after", 12, "--out", tmp_path)
    demo("footing_bsm", "--restart", tmp_path)
    data = pvbatch_json(os.path.join(ROOT, "tests", "paraview_footing_check.py"), tmp_path / "paraview_footing.py",
                        tmp_path / "render.png")
    summary = json.loads((tmp_path / "summary.json").read_text())
    continuum, grains = data["continuum"], data["grains"]
    assert len(continuum["times"]) == 5 and continuum["times"] == grains["times"]
    assert np.isclose(continuum["times"][-1], summary["coarse_steps"] * summary["dt"], rtol=1e-12)
    assert grains["points"] == summary["grains_real"] + summary["grains_virtual"]
    assert {"coarse", "fine", "displacement", "radius", "virtual"} <= set(grains["arrays"])
    assert {"u", "phi"} <= set(continuum["arrays"])
    assert (tmp_path / "render.png").stat().st_size > 10000
