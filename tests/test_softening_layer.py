"""The softening shear layer (cosserat_fenicsx.scenes.softening_layer): assembly checks on
small layers, and the regularisation property (slow, `make benchmark` runs it with the
full benchmark in benchmarks/ehlers/softening_layer.py)."""
import numpy as np
import pytest

from cosserat_fenicsx.scenes.softening_layer import LayerSettings, SofteningLayer
from cosserat_fenicsx.stepping import LoadSteppingError

pytestmark = pytest.mark.serial   # no dolfinx, no MPI content


def _sheared(steps_done, **kw):
    s = LayerSettings(**dict(dict(height=4e-3, cell_size=0.5e-3, weak_size=1e-3, shear=0.2, steps=40,
                                  material=dict(l_c=0.5e-3, k_sigma=0.0)), **kw))
    layer = SofteningLayer(s)
    layer.s.steps = steps_done        # stop early: a plastic, hardening state
    layer.run()
    return layer


@pytest.mark.parametrize("kw", [dict(), dict(material=dict(l_c=0.5e-3, k_sigma=10.0)), dict(micropolar=False)],
                         ids=["k_sigma_0", "k_sigma_10", "classical"])
def test_global_tangent_is_the_derivative_of_the_residual(kw):
    layer = _sheared(6, **kw)
    x = layer.x.copy()
    x[layer.top_u1] *= 1.02                        # a trial state beyond the converged one
    r, K = layer._evaluate(x, 1.0)
    assert layer.state_new[:, layer.materials[0].state_index["Lambda"]].max() > 0   # plastic
    free = layer.free
    rng = np.random.default_rng(1)
    # strain-sized perturbation 1e-8: displacements scaled by h, rotations as they are
    d = rng.standard_normal(x.size) * 1e-8
    d[:2 * layer.nu] *= layer.h
    d[layer.fixed] = 0.0
    rp, _ = layer._evaluate(x + d, 1.0)
    rm, _ = layer._evaluate(x - d, 1.0)
    fd = (rp - rm)[free] / 2
    err = np.linalg.norm(fd - (K @ d)[free]) / np.linalg.norm(fd)
    assert err < 1e-5, err


def test_equilibrium_of_the_layer():
    """sigma12 and sigma22 are constant through the layer (sigma12' = sigma22' = 0) and
    sigma22 equals the applied -p, up to the discretisation of the stress."""
    layer = _sheared(8)
    tau = layer.flux[:, 2]
    assert np.ptp(tau) < 2e-3 * abs(tau.mean())
    assert np.allclose(layer.flux[:, 1], -layer.s.confining, rtol=2e-3)
    assert tau.mean() > 0.3 * layer.s.confining       # it is being sheared


def test_homogeneous_layer_micropolar_equals_classical():
    """Without the weak zone the layer stays homogeneous: phi = -u1'/2, the stress is
    symmetric and the micropolar model gives the classical response (spec 10 item 9)."""
    kw = dict(weak_size=0.0)
    micro = _sheared(10, **kw)
    classical = _sheared(10, micropolar=False, **kw)
    t_m = np.array([r["tau"] for r in micro.history])
    t_c = np.array([r["tau"] for r in classical.history])
    assert t_m.shape == t_c.shape
    assert np.allclose(t_m, t_c, rtol=1e-6)
    assert np.allclose(micro.flux[:, 2], micro.flux[:, 3], rtol=1e-6)


@pytest.mark.slow
def test_band_thickness_converges_for_k_sigma_0_and_follows_h_for_classical():
    """Regularisation (issue 3 item 6), on a layer of 20 mm with l_c = 0.1 mm."""
    def H(h, **kw):
        s = LayerSettings(height=0.02, cell_size=h, weak_size=1e-3, shear=0.3, steps=150, **kw)
        layer = SofteningLayer(s)
        try:
            layer.run()
        except LoadSteppingError:
            # non-regularised bands reach strains the local Newton cannot follow (> 200 %);
            # the band has long formed by then: measure the last converged state
            assert layer.history[-1]["shear"] > 0.06
        return layer.band().thickness

    micro = [H(h, material=dict(l_c=1e-4, k_sigma=0.0)) for h in (2e-4, 1e-4)]
    assert abs(micro[1] / micro[0] - 1) < 0.05, micro
    classical = [H(h, micropolar=False) for h in (4e-4, 2e-4)]
    assert classical[1] / classical[0] < 0.7, classical
