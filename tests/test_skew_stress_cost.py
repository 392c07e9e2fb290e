"""The skew stress a decoupled shear band costs, kernel against closed form.

docs/results/regularisation.md ("Why a large k_sigma does not regularise"): a point sheared with the
Cosserat rotation frozen (band shear in the skew strain) flows plastically on the yield
surface (2.76) for every k_sigma > 0, with sigma_skw = (psi1 / k_sigma) S12 (flow rule 2.79 with
the potential 2.78), and carries the traction sigma12 = f T, f = (1 + psi1/k_sigma) /
sqrt(1 + psi1^2/k_sigma), where T is the traction of the coupled state (phi following the
material rotation) on the same surface. The closed form is written here again on purpose
(not imported from the benchmark), so a slip in either would show.
"""
import math

import numpy as np
import pytest

from benchmarks.ehlers.skew_stress_cost import shear_path
from cosserat_fenicsx.materials.ehlers import EhlersMaterial
from cosserat_fenicsx.materials.ehlers.material_point import consolidate_state

pytestmark = pytest.mark.serial          # material point only: the serial pass

PSI1 = 1.85          # Table 6.4
GAMMA_MAX, STEPS = 0.3, 120   # past the peak (gamma ~ 0.12-0.14), a second or two per path


def f_closed(k_sigma):
    return (1.0 + PSI1 / k_sigma) / math.sqrt(1.0 + PSI1 ** 2 / k_sigma)


@pytest.fixture(scope="module", params=[1.0, 10.0])
def paths(request):
    k = request.param
    m = EhlersMaterial.hostun(k_sigma=k)
    assert m.parameters.psi1 == PSI1
    st = consolidate_state(m, -100e3)
    c = shear_path(m, st, 0.0, "isotropic", GAMMA_MAX, STEPS)
    d = shear_path(m, st, 1.0, "isotropic", GAMMA_MAX, STEPS)
    return k, c, d


def test_decoupled_state_flows_on_the_yield_surface(paths):
    """Also below psi1^2 = 3.4 (k_sigma = 1), where the old argument said it could not fit."""
    k, c, d = paths
    s = d["gamma"] >= 0.05
    assert np.all(d["Lambda"][s] > 0.0)                       # plastic flow ...
    assert np.all(d["F"] < 1e-4 * d["T"])                     # ... on the surface (tiny Perzyna overstress)
    # the skew strain gamma/2 is plastic but for its elastic part sigma_skw / (2 mu_c) (2.73)
    mu_c = 91.0e6
    np.testing.assert_allclose(d["eps_p_skw"] + d["skw"] / (2 * mu_c), d["gamma"] / 2, rtol=1e-6, atol=1e-9)
    assert d["eps_p_skw"][-1] > 0.99 * GAMMA_MAX / 2
    np.testing.assert_allclose(d["skw"][s] / d["S12"][s], PSI1 / k, rtol=5e-3)


def test_traction_factor_matches_closed_form(paths):
    k, c, d = paths
    s = d["gamma"] >= 0.05
    np.testing.assert_allclose(c["sig12"][s] / c["T"][s], 1.0, rtol=1e-4)   # coupled: no skew stress
    np.testing.assert_allclose(d["sig12"][s] / d["T"][s], f_closed(k), rtol=1e-3)
    # the two paths' own peaks (different hardening histories): f holds to about 1 %
    ratio = d["sig12"].max() / c["sig12"].max()
    print(f"k_sigma = {k}: f = {f_closed(k):.4f}, peak ratio {ratio:.4f}")
    assert ratio == pytest.approx(f_closed(k), rel=0.01)
    assert ratio > 1.0
