"""Cross-code verification against YADE (written by others): the same packing, linear
Cundall-Strack law, time step and quasi-static solve give the same stress.
Slow (runs YADE, about 20 s); skipped when the Debian package ``yade`` is not installed."""
import shutil

import numpy as np
import pytest

pytestmark = [pytest.mark.serial, pytest.mark.slow]


@pytest.mark.skipif(shutil.which("yade") is None, reason="YADE not installed (apt-get install yade)")
def test_stress_after_quasi_static_solve_matches_yade(tmp_path):
    from benchmarks.dem import dem_speed
    from demcell.contact_law import ContactLaw
    from demcell.relaxation import stable_time_step
    kn, ks = 3e6, 2.4e6
    yade = shutil.which("yade")
    _, export = dem_speed.yade_side(yade, 228, str(tmp_path), 1, kn, ks, 1e-3, 1, 600)   # packing
    st, _ = dem_speed.demcell_state(export)
    dt = stable_time_step(st.radius, st.mass, st.inertia, ContactLaw(kn=kn, ks=ks), 0.5)
    y, export = dem_speed.yade_side(yade, 228, str(tmp_path), 400, kn, ks, 1e-3, 100000, 600, dt)
    d = dem_speed.demcell_side(export, 400, kn, ks, 1e-3, 100000, repeat=1)
    assert y["solve_converged"] and d["solve_converged"]
    sy, sd = np.array(y["solve_stress"]), np.array(d["solve_stress"])
    assert np.abs(sd - sy).max() < 1e-3 * np.abs(sy).max()
