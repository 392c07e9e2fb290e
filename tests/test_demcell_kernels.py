"""The fast force loop of the plain frictional law against the general loop, bit for bit.

``relaxation.compute_forces`` sends a cell whose law has no bond, dashpot, rolling spring,
frozen contact or image spin through ``_plain_pair_forces`` (three short loops);
``plain_path=False`` forces the general loop. Both must give the same bits: forces, moments,
contact history and the sums (stress, energy, counts) over a sequence of random moves
in which contacts slide, open and close. For the other laws the dispatcher must keep
the general loop (a law it wrongly took as plain would lose its bonds or dashpots and differ).
"""
import math

import numpy as np
import pytest

import demcell as dc
from demcell.relaxation import compute_forces
from demcell.slots import N_OUT, O_NCONT, O_NSLIDE

pytestmark = pytest.mark.serial

PAIR = ("fn", "fs", "mr", "bonded", "touching", "d_prev")


@pytest.fixture(scope="module")
def packing60():
    st, _ = dc.generate_packing(60, pressure=10.0, seed=3)
    return st


def forces(st, law, dt, out, plain_path):
    compute_forces(st.radius, st.mass, st.s, st.dtheta, st.force, st.moment, st.h, st.pair_i,
                   st.pair_j, st.fn, st.fs, st.mr, st.bonded, st.touching, st.d_prev, st.n_pairs,
                   law, dt, out, 0.0, 0.0, plain_path)


def random_walk(packing, law, bonds=False, moves=150):
    """The two loops on two copies of the packing through the same random moves; returns the
    number of sliding contacts summed over the moves and the contacts opened and closed."""
    st = {True: packing.copy(), False: packing.copy()}
    if bonds:
        for w in st.values():
            m = w.n_pairs
            w.bonded[:m] = w.touching[:m]
            w.bonded[:m:2] = 0          # half of them: both bonded and plain contacts
    la = law.as_array()
    dt = dc.DemCell(packing.copy(), law).dt
    radius = float(np.mean(packing.radius))
    width = math.sqrt(abs(np.linalg.det(packing.h)))
    rng = np.random.default_rng(7)
    slid = opened = closed = 0
    for _ in range(moves):
        ds = 3e-4 * radius / width * rng.standard_normal(packing.s.shape)
        dth = 3e-3 * rng.standard_normal(packing.n_particles)
        outs = {}
        for flag, w in st.items():
            before = w.touching[:w.n_pairs].copy()
            w.s += ds
            w.dtheta[:] = dth
            outs[flag] = np.zeros(N_OUT)
            forces(w, la, dt, outs[flag], flag)
        a, b = st[True], st[False]
        m = a.n_pairs
        for f in ("force", "moment"):
            assert np.array_equal(getattr(a, f), getattr(b, f)), f
        for f in PAIR:
            assert np.array_equal(getattr(a, f)[:m], getattr(b, f)[:m]), f
        assert np.array_equal(outs[True], outs[False])
        assert outs[True][O_NCONT] > 0
        slid += int(outs[True][O_NSLIDE])
        now = a.touching[:m]
        opened += int(np.count_nonzero(before > now))
        closed += int(np.count_nonzero(before < now))
    return slid, opened, closed


@pytest.mark.parametrize("law", [dict(friction=0.0), dict(friction=0.3), dict(friction=math.inf),
                                 dict(friction=0.3, cohesion_normal=0.05, cohesion_shear=0.05)])
def test_plain_loop_equals_general_loop(packing60, law):
    """(The last law has cohesion but no bond: cohesion acts only through bonds, so it is plain.)"""
    slid, opened, closed = random_walk(packing60, dc.ContactLaw(kn=1.0e4, ks=2.0e3, **law))
    # the walk must exercise what the two loops could treat differently
    assert opened > 0 and closed > 0
    if 0.0 < law["friction"] < math.inf:
        assert slid > 0


@pytest.mark.parametrize("law, bonds", [
    (dict(friction=0.3, rolling_stiffness=1.0, rolling_friction=0.1), False),
    (dict(friction=0.3, normal_damping=0.05, tangential_damping=0.05), False),
    (dict(friction=0.3), True),
    (dict(friction=0.3, cohesion_normal=0.05, cohesion_shear=0.05), True),
])
def test_other_laws_keep_the_general_loop(packing60, law, bonds):
    random_walk(packing60, dc.ContactLaw(kn=1.0e4, ks=2.0e3, **law), bonds=bonds, moves=40)


def test_bonds_change_the_forces(packing60):
    """The check above can fail: a cell with bonds, through the general loop, differs from the
    same cell without them, which is what the plain loop would compute if it took the cell."""
    law = dc.ContactLaw(kn=1.0e4, ks=2.0e3, friction=0.3, cohesion_normal=1e3,
                        cohesion_shear=1e3).as_array()
    bonded = packing60.copy()
    m = bonded.n_pairs
    bonded.bonded[:m] = bonded.touching[:m]
    bonded.h[:] = bonded.h * 1.01          # the cell stretched 1 %: contacts open, bonds hold
    free = bonded.copy()
    free.bonded[:m] = 0
    out_b, out_f = np.zeros(N_OUT), np.zeros(N_OUT)
    forces(bonded, law, 1e-6, out_b, False)
    forces(free, law, 1e-6, out_f, True)
    assert out_b[O_NCONT] > out_f[O_NCONT]
    assert not np.array_equal(bonded.force, free.force)


def test_stale_numba_cache_is_dropped(tmp_path):
    """A cached caller keeps its compiled callee (Numba #6845): demcell drops its cache when any
    source changes, and only then."""
    from demcell.numba_cache import clear_stale_cache
    (tmp_path / "kernel.py").write_text("X = 1\n")
    cache = tmp_path / "__pycache__"
    cache.mkdir()
    (cache / "kernel.f-1.py311.nbi").write_text("index")
    (cache / "kernel.cpython-311.pyc").write_text("bytecode")
    assert clear_stale_cache(str(tmp_path))              # no stamp yet: cleared
    assert not (cache / "kernel.f-1.py311.nbi").exists()
    assert (cache / "kernel.cpython-311.pyc").exists()   # Python's own cache is left alone
    (cache / "kernel.f-1.py311.nbi").write_text("index")
    assert not clear_stale_cache(str(tmp_path))          # same sources: kept
    assert (cache / "kernel.f-1.py311.nbi").exists()
    (tmp_path / "kernel.py").write_text("X = 2\n")
    assert clear_stale_cache(str(tmp_path))              # edited: cleared
    assert not (cache / "kernel.f-1.py311.nbi").exists()


def test_mechanical_coordination_number_against_its_definition(packing60):
    """homogenize counts C' (contacts between two particles that each have >= 2 contacts) in
    Numba; here C' is counted from the definition (000 section 4.1) in plain Python, on a
    packing with rattlers and on a hexagonal lattice (no rattler: n' = n = 6)."""
    law = dc.ContactLaw(kn=1e4, ks=2e3, friction=0.4)
    cell = dc.DemCell(packing60.copy(), law)
    cell.set_deformation(np.eye(2))
    cell.solve()
    st = cell.state
    n = st.n_pairs
    # two rattlers with one contact left each, one first and one second in the pair of that
    # contact (homogenize reads the flags as they are); the second is picked away from the
    # first and its partner
    taken = set()
    for side, other in ((st.pair_i, st.pair_j), (st.pair_j, st.pair_i)):
        k0 = next(k for k in range(n) if st.touching[k] and not {side[k], other[k]} & taken)
        p = side[k0]
        st.touching[[k for k in range(n) if k != k0 and p in (st.pair_i[k], st.pair_j[k])]] = 0
        taken |= {p, other[k0]}
    touching = [k for k in range(n) if st.touching[k]]
    z = np.zeros(st.n_particles, int)
    for k in touching:
        z[st.pair_i[k]] += 1
        z[st.pair_j[k]] += 1
    active = z >= 2
    c_mech = sum(1 for k in touching if active[st.pair_i[k]] and active[st.pair_j[k]])
    h = cell.homogenized()
    assert 0 < c_mech < len(touching), "the packing should hold rattlers or contacts to them"
    assert h.mechanical_coordination_number == 2.0 * c_mech / active.sum()
    assert h.coordination_number == 2.0 * len(touching) / st.n_particles

    lattice = dc.DemCell(dc.hexagonal_lattice(6, 6, radius=0.01, overlap=1e-5), law)
    lattice.set_deformation(np.eye(2))
    lattice.solve()
    h = lattice.homogenized()
    assert h.coordination_number == pytest.approx(6.0) and h.mechanical_coordination_number == pytest.approx(6.0)
