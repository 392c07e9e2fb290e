"""demcell verification against references nobody here wrote.

* hexagonal packing: closed-form moduli K = sqrt(3) kn / 2, G = sqrt(3) (kn + kt) / 4
  (affine deformation is exact on a monodisperse triangular lattice; e.g. Kruyt &
  Rothenburg; equivalently Poisson ratio (kn - kt) / (3 kn + kt));
* two-disc collision vs the linear spring-dashpot solution: duration pi / (w0 sqrt(1 - xi^2)),
  restitution exp(-xi pi / sqrt(1 - xi^2)), w0 = sqrt(kn / m_eff);
* energy conservation with all damping off;
* Kruyt operator (001 eq. 13) vs perturbation tangent (001 eq. 6) in the elastic regime;
  PSTLO (001 appendix B) vs DEMQO (001 eq. 20); PSTLO with sliding contacts vs the
  perturbation tangent where contacts slide;
* invariance of the stress under a rigid rotation of F; symmetry of the Cauchy stress.
"""
import math

import numpy as np
import pytest

import demcell as dc
from demcell.interface import RelaxationOptions
from demcell.periodic_cell import rotation

pytestmark = pytest.mark.serial

KN, KS = 1.0e4, 2.0e3


@pytest.fixture(scope="module")
def packing60():
    st, info = dc.generate_packing(60, pressure=10.0, seed=3)
    return st


def hex_cell(law, overlap=1e-5, jitter=0.0, tol=1e-10):
    st = dc.hexagonal_lattice(6, 6, radius=0.01, overlap=overlap)
    if jitter:   # displacements of jitter x spacing (below the overlap: no contact lost)
        rng = np.random.default_rng(0)
        st.s += jitter * rng.standard_normal(st.s.shape) / 6.0
    opts = RelaxationOptions(tol=tol, criterion="energy", check_every=20, max_steps=400_000)
    cell = dc.DemCell(st, law, opts)
    res = cell.solve()      # relax the (jittered) lattice at F = I
    assert res.converged, res.message
    cell.commit()
    return cell


@pytest.mark.parametrize("friction", [0.0, 0.5])
def test_hexagonal_packing_moduli_closed_form(friction):
    law = dc.ContactLaw(kn=KN, ks=KS, friction=friction)
    cell = hex_cell(law, jitter=3e-6)
    sig0 = cell.cauchy_stress()
    kt = KS if friction > 0 else 0.0
    K = math.sqrt(3.0) * KN / 2.0
    G = math.sqrt(3.0) * (KN + kt) / 4.0
    eps = 1e-6
    for E, expected in [(np.eye(2), 2.0 * K * np.eye(2)),                       # bulk
                        (np.diag([1.0, -1.0]), 2.0 * G * np.diag([1.0, -1.0])),  # pure shear
                        (np.array([[0.0, 1.0], [1.0, 0.0]]), 2.0 * G * np.array([[0.0, 1.0], [1.0, 0.0]]))]:
        trial = cell.copy()
        trial.set_deformation(np.eye(2) + eps * E)
        assert trial.solve().converged
        dsig = (trial.cauchy_stress() - sig0) / eps
        assert np.abs(dsig - expected).max() < 2e-3 * np.abs(expected).max(), (E, dsig, expected)


def test_two_disc_collision_spring_dashpot():
    xi, R, rho, v0 = 0.3, 0.01, 2.0e3, 0.05
    law = dc.ContactLaw(kn=KN, ks=KS, friction=0.5, normal_damping=xi)
    m = rho * math.pi * R ** 2
    w0 = math.sqrt(KN / (0.5 * m))
    t_c = math.pi / (w0 * math.sqrt(1.0 - xi ** 2))
    e_ref = math.exp(-xi * math.pi / math.sqrt(1.0 - xi ** 2))
    L = 0.2
    st = dc.CellState.new(np.array([R, R]), np.array([[0.5 - 1.05 * R / L, 0.5], [0.5 + 1.05 * R / L, 0.5]]),
                          np.diag([L, L]), rho)
    st.v[0, 0], st.v[1, 0] = v0, -v0
    dt = t_c / 4000.0
    cell = dc.DemCell(st, law, RelaxationOptions(dt=dt))
    steps_touching, started = 0, False
    for _ in range(20000):
        cell.run_dynamics(1)
        if cell.contact_count():
            started = True
            steps_touching += 1
        elif started:
            break
    v_rel_after = cell.state.v[1, 0] - cell.state.v[0, 0]
    assert abs(steps_touching * dt - t_c) / t_c < 2e-3
    assert abs(v_rel_after / (2 * v0) - e_ref) / e_ref < 5e-3


@pytest.mark.parametrize("friction, amplitude", [(0.0, 1.0), (math.inf, 1e-3)])
def test_energy_conservation_without_damping(packing60, friction, amplitude):
    """Frictionless: a pure central potential, any amplitude (contacts open and close).
    Tangential springs without sliding are conservative only while contacts persist (a
    spring dropped at separation takes its energy with it), hence the small amplitude."""
    law = dc.ContactLaw(kn=KN, ks=KS, friction=friction)
    cell = dc.DemCell(packing60.copy(), law, RelaxationOptions(dt_safety=0.05))
    rng = np.random.default_rng(1)
    st = cell.state
    e_pot = cell.homogenized().potential_energy
    st.v[:] = rng.standard_normal(st.v.shape)
    st.omega[:] = rng.standard_normal(st.omega.shape) / st.radius
    scale = math.sqrt(amplitude * e_pot / cell.homogenized().kinetic_energy)  # E_kin = amplitude E_pot
    st.v *= scale
    st.omega *= scale
    energies = []
    for _ in range(40):
        cell.run_dynamics(100, damping=0.0)
        h = cell.homogenized()
        energies.append(h.kinetic_energy + h.potential_energy)
    energies = np.array(energies)
    assert np.abs(energies - energies[0]).max() / energies[0] < 1e-2
    # and damping on really dissipates (translational energy; frictionless discs keep spinning)
    cell.run_dynamics(2000, damping=0.7)
    h = cell.homogenized()
    assert h.kinetic_energy + h.potential_energy < energies[-1] - 0.3 * amplitude * e_pot


def test_kruyt_equals_perturbation_on_hexagonal_lattice():
    law = dc.ContactLaw(kn=KN, ks=KS, friction=math.inf)
    cell = hex_cell(law)
    C_k = cell.tangent("kruyt")
    C_p = cell.tangent("perturbation", eps=1e-7)
    # symmetric directions of dF (the Kruyt operator ignores particle rotations, 001 section 4.1)
    for dF in (np.diag([1.0, 0.0]), np.diag([0.0, 1.0]), np.array([[0.0, 0.5], [0.5, 0.0]])):
        a = C_k @ dF.reshape(4)
        b = C_p @ dF.reshape(4)
        assert np.abs(a - b).max() < 1e-3 * np.abs(a).max()


def test_kruyt_is_an_upper_bound_of_the_elastic_tangent(packing60):
    law = dc.ContactLaw(kn=KN, ks=KS, friction=math.inf)
    cell = dc.DemCell(packing60.copy(), law, RelaxationOptions(tol=1e-9, check_every=20))
    assert cell.solve().converged
    cell.commit()
    C_k = cell.tangent("kruyt")
    C_p = cell.tangent("perturbation", eps=1e-6)
    C_q = cell.tangent("demqo", eps=1e-6)
    rng = np.random.default_rng(2)
    for _ in range(5):
        e = rng.standard_normal((2, 2))
        e = 0.5 * (e + e.T).reshape(4)
        wk, wp, wq = e @ C_k @ e, e @ C_p @ e, e @ C_q @ e
        assert wk >= wp > 0.0 and wk >= wq > 0.0
        assert abs(wp - wq) < 0.05 * wp      # elastic regime: CTO ~ DEMQO


def sliding_cell():
    """The FEM x DEM reference cell (228 discs, 10 N/m, mu 0.4, unbalanced-force ratio 1e-3)
    committed at 1 % biaxial strain and solved 0.2 % further: a load step's iterate, with
    contacts sliding."""
    law = dc.ContactLaw(kn=KN, ks=KS, friction=0.4)
    options = RelaxationOptions(tol=1e-3, damping=0.7, criterion="force")
    state, _ = dc.generate_packing(228, pressure=10.0, law=law, seed=0)
    cell = dc.reference_cell(state, law, options, 10.0)
    cell.set_deformation(np.diag([1.005, 0.99]))
    assert cell.solve().converged
    cell.commit()
    cell.set_deformation(np.diag([1.006, 0.988]))
    assert cell.solve().converged
    return cell


def test_pstlo_sliding_follows_the_consistent_tangent():
    """Against the perturbation tangent (CTO, 001 eq. 6: rolled back and re-solved, the
    derivative the macro Newton needs) on a cell whose contacts slide: PSTLO (every contact
    sticking) is 30-40 % off, PSTLO with the contacts near their Coulomb limit sliding within
    15 % (benchmarks/dem/dem_tangent_sliding.py: 8 % in the median of 20 states)."""
    cell = sliding_cell()
    C_cto = cell.tangent("perturbation", eps=1e-5)
    error = {kind: np.linalg.norm(cell.tangent(kind) - C_cto) / np.linalg.norm(C_cto)
             for kind in ("pstlo", "pstlo_sliding")}
    assert error["pstlo"] > 0.25, error
    assert error["pstlo_sliding"] < 0.15, error
    # the loading direction (dF11, dF22) = (1/2, -1), the one a Newton correction of the step takes
    D = np.array([0.5, 0.0, 0.0, -1.0])
    along = {kind: np.linalg.norm((cell.tangent(kind) - C_cto) @ D) / np.linalg.norm(C_cto @ D)
             for kind in ("pstlo", "pstlo_sliding")}
    assert along["pstlo_sliding"] < 0.5 * along["pstlo"], along


def test_pstlo_sliding_is_pstlo_without_friction_limit(packing60):
    """No contact can reach an infinite Coulomb limit: the operators are the same bits; a
    micropolar cell refuses it by name."""
    law = dc.ContactLaw(kn=KN, ks=KS, friction=math.inf)
    cell = dc.DemCell(packing60.copy(), law, RelaxationOptions(tol=1e-6, check_every=20))
    cell.set_deformation(np.array([[0.998, 0.001], [0.0, 1.001]]))
    assert cell.solve().converged
    assert np.array_equal(cell.tangent("pstlo_sliding"), cell.tangent("pstlo"))
    micropolar = dc.DemCell(packing60.copy(), law, rotation_mode="micropolar")
    with pytest.raises(dc.InputError, match="pstlo_sliding.*Cauchy"):
        micropolar.tangent("pstlo_sliding", measure="micropolar")


def test_floor_stiffness_on_an_isotropic_closed_form():
    """pstlo_sliding's floor (tangent.floor_stiffness) on the 2D isotropic tangent
    C_ijkl = lam d_ij d_kl + G (d_ik d_jl + d_il d_jk), whose symmetric part on symmetric
    strains has the eigenvalues 2 (lam + G) (volumetric) and 2 G (twice, deviatoric): with
    G = 0 (a mechanism, a cell at its peak) the deviatoric pair is raised to exactly the floor,
    the volumetric stiffness and the response to a spin (none) are kept; a stiff shear
    modulus is left alone, the same array."""
    from demcell.tangent import floor_stiffness, from_tensor4
    d = np.eye(2)
    def isotropic(lam, G):
        T = (lam * np.einsum("ij,kl->ijkl", d, d)
             + G * (np.einsum("ik,jl->ijkl", d, d) + np.einsum("il,jk->ijkl", d, d)))
        return from_tensor4(T)
    lam = 3000.0
    C = floor_stiffness(isotropic(lam, 0.0), fraction=0.05)
    floor = 0.05 * 2 * lam
    np.testing.assert_allclose(C, isotropic(lam - floor / 2, floor / 2), rtol=1e-12, atol=1e-9)
    spin = np.array([0.0, 1.0, -1.0, 0.0])
    np.testing.assert_allclose(C @ spin, 0.0, atol=1e-9)
    stiff = isotropic(lam, 1000.0)
    assert floor_stiffness(stiff, fraction=0.05) is stiff


@pytest.mark.parametrize("rolling", [0.0, 0.5])
def test_pstlo_linearization_equals_demqo(packing60, rolling):
    """001 appendix B (analytic linearization with pre-stress terms, one sparse solve) against
    001 eq. 20 (four frozen-contact dynamic relaxations): two independent routes."""
    law = dc.ContactLaw(kn=KN, ks=KS, friction=math.inf, rolling_stiffness=rolling)
    cell = dc.DemCell(packing60.copy(), law, RelaxationOptions(tol=1e-10, check_every=20))
    cell.set_deformation(np.array([[0.998, 0.001], [0.0, 1.001]]))
    assert cell.solve().converged
    C_s = cell.tangent("pstlo")
    C_q = cell.tangent("demqo", eps=1e-7)
    assert np.abs(C_s - C_q).max() < 1e-4 * np.abs(C_q).max()
    # rows 12 and 21 agree: the increment of the Cauchy stress stays symmetric
    assert np.abs(C_s[1] - C_s[2]).max() < 1e-6 * np.abs(C_s).max()


def test_stress_invariant_under_rigid_rotation(packing60):
    law = dc.ContactLaw(kn=KN, ks=KS, friction=0.4)
    opts = RelaxationOptions(tol=1e-9, check_every=20)
    U = np.array([[0.998, 0.0005], [0.0005, 1.001]])
    a = dc.DemCell(packing60.copy(), law, opts)
    a.set_deformation(U)
    assert a.solve().converged
    # rotate the equilibrated, frictional (path-dependent) cell rigidly: F = U -> Q U
    Q = rotation(0.7)
    b = a.copy()
    b.set_deformation(Q @ U)
    res = b.solve()
    assert res.converged and res.substeps > 1
    sa, sb = a.cauchy_stress(), b.cauchy_stress()
    assert np.abs(Q @ sa @ Q.T - sb).max() < 1e-3 * np.abs(sa).max()
    Pa, Pb = a.pk1_stress(), b.pk1_stress()
    assert np.abs(Q @ Pa - Pb).max() < 1e-3 * np.abs(Pa).max()


@pytest.mark.parametrize("rolling", [0.0, 1.0])
def test_cauchy_stress_symmetric_at_equilibrium(packing60, rolling):
    law = dc.ContactLaw(kn=KN, ks=KS, friction=0.4, rolling_stiffness=rolling, rolling_friction=0.1)
    cell = dc.DemCell(packing60.copy(), law, RelaxationOptions(tol=1e-10, check_every=20))
    cell.set_deformation(np.array([[0.995, 0.004], [-0.002, 1.002]]))
    assert cell.solve().converged
    s = cell.cauchy_stress()
    assert abs(s[0, 1] - s[1, 0]) < 1e-4 * np.abs(s).max()
