"""Many periodic cells in one struct of arrays, solved by one Numba call.

A FEM x DEM rank holds hundreds to thousands of cells. ``CellBatch`` keeps all of them in
one store, the layout of ``state.pack_states``: every per-particle array concatenated over
the cells (offsets ``p_off``), every pair array at each cell's capacity (offsets ``q_off``),
per-cell values stacked; the committed copy has the same layout, so commit and rollback are
slice copies. ``solve(rows)`` runs ``quasistatic.solve_cell`` (the function DemCell.solve
runs) on the cells ``rows`` in a Numba ``prange``: the threads of the rank
(``NUMBA_NUM_THREADS`` or ``numba.set_num_threads``) share the cells, with no Python per cell.
``homogenize`` and ``kruyt`` are batched the same way (homogenization.contact_sums,
tangent._kruyt_sum). Results are the bits of a DemCell solved alone (tests/test_demcell_batch.py).

Threads take the cells in bins balanced by a cost estimate (the DEM steps of each cell's
last solve, or equal costs at first): Numba's prange splits its range statically, and a
cell in a shear band can cost ten times one outside it.

``view(k)`` gives a DemCell whose state arrays are views into the store (for the tangents
that are not batched: pstlo's sparse solve, DEMQO and CTO's perturbations work on copies).
"""
import numpy as np
from numba import get_num_threads, njit, prange

from . import checks
from . import quasistatic as qs
from .slots import KN, KS, MU
from .errors import InputError
from .homogenization import contact_sums
from .interface import DemCell
from .periodic_cell import deformation_gradient
from .state import PAIR_FIELDS, PARTICLE_FIELDS, CellState
from .tangent import kruyt_tensor
from . import slots

#: per-cell float and int scalars of a state (quasistatic's cellf / celli)
CELLF = ("time", "phi", "kappa0", "kappa1")


@njit(cache=True, parallel=True)
def _solve_rows(order, bins, p_off, q_off, radius, mass, inertia, s, v, theta, omega, dtheta, force, moment,
                s_build, h, h_build, h_ref, pair_i, pair_j, fn, fs, mr, bonded, touching, d_prev, cellf, celli,
                law, dt, opts, target, work, iwork, result, code):
    """solve_cell on the cells order[bins[t]:bins[t+1]] for each thread bin t (cells whose
    code is not 0 are skipped: done, or waiting for larger pair arrays)."""
    for t in prange(bins.shape[0] - 1):
        for r in range(bins[t], bins[t + 1]):
            c = order[r]
            if code[c] != 0:
                continue
            p0, p1, q0, q1 = p_off[c], p_off[c + 1], q_off[c], q_off[c + 1]
            status = qs.solve_cell(radius[p0:p1], mass[p0:p1], inertia[p0:p1], s[p0:p1], v[p0:p1], theta[p0:p1],
                                   omega[p0:p1], dtheta[p0:p1], force[p0:p1], moment[p0:p1], s_build[p0:p1],
                                   h[c], h_build[c], h_ref[c], pair_i[q0:q1], pair_j[q0:q1], fn[q0:q1], fs[q0:q1],
                                   mr[q0:q1], bonded[q0:q1], touching[q0:q1], d_prev[q0:q1], cellf[c], celli[c],
                                   law[c], dt[c], opts[c], target[c], work[c], iwork[c], result[c])
            code[c] = 1 if status == qs.DONE else 2


@njit(cache=True, parallel=True)
def _homogenize_rows(rows, p_off, q_off, h, s, radius, pair_i, pair_j, fn, fs, mr, touching, celli, law, h_ref,
                     micropolar, cauchy, couple, fabric, counts):
    for r in prange(rows.shape[0]):
        c = rows[r]
        p0, p1, q0, q1 = p_off[c], p_off[c + 1], q_off[c], q_off[c + 1]
        sig, cou, fab, nc, nsl, _ = contact_sums(h[c], s[p0:p1], radius[p0:p1], pair_i[q0:q1], pair_j[q0:q1],
                                                 fn[q0:q1], fs[q0:q1], mr[q0:q1], touching[q0:q1], celli[c, 0],
                                                 law[c, MU], h_ref[c], micropolar)
        cauchy[r] = sig
        couple[r] = cou
        fabric[r] = fab
        counts[r, 0] = nc
        counts[r, 1] = nsl


@njit(cache=True, parallel=True)
def _kruyt_rows(rows, p_off, q_off, h, h_ref, s, pair_i, pair_j, touching, celli, law, T):
    for r in prange(rows.shape[0]):
        c = rows[r]
        p0, p1, q0, q1 = p_off[c], p_off[c + 1], q_off[c], q_off[c + 1]
        kt = law[c, KS] if law[c, MU] > 0.0 else 0.0
        T[r] = kruyt_tensor(h[c], h_ref[c], s[p0:p1], pair_i[q0:q1], pair_j[q0:q1], touching[q0:q1], celli[c, 0],
                            law[c, KN], kt)


@njit(cache=True)
def gradients_of(rows, h, h_ref, F):
    """F[r] = h[c] h_ref[c]^-1 of the cells c = rows[r] (periodic_cell.deformation_gradient),
    in one call."""
    for r in range(rows.shape[0]):
        F[r] = deformation_gradient(h[rows[r]], h_ref[rows[r]])


@njit(cache=True)
def _gradients_and_counts(rows, q_off, h, h_ref, touching, celli, F, counts):
    """F = h h_ref^-1 and the touching contacts of the cells rows."""
    gradients_of(rows, h, h_ref, F)
    for r in range(rows.shape[0]):
        c = rows[r]
        n = 0
        for k in range(q_off[c], q_off[c] + celli[c, 0]):
            n += touching[k]
        counts[r] = n


def _ranges(off, rows):
    """Indices off[c] .. off[c+1]-1 of every c in rows, concatenated (no Python per cell)."""
    starts = off[rows]
    lens = off[rows + 1] - starts
    total = int(lens.sum())
    shift = np.repeat(starts - np.concatenate([[0], np.cumsum(lens)[:-1]]), lens)
    return shift + np.arange(total, dtype=np.int64)


def _bins(rows, cost, n_threads):
    """rows regrouped into n_threads bins of similar total cost (greedy, largest first):
    (order, bin offsets). Deterministic; the bits of a cell do not depend on its bin."""
    rows = np.asarray(rows, dtype=np.int64)
    n_threads = max(1, min(int(n_threads), len(rows)))
    if n_threads == 1:
        return rows, np.array([0, len(rows)], dtype=np.int64)
    # a cell never solved (nan) is assumed to cost the median of the others: with a cost of
    # 1 step, one thread would get all of them against one solved cell on the other
    known = cost[np.isfinite(cost)]
    cost = np.where(np.isfinite(cost), cost, np.median(known) if len(known) else 1.0)
    c = cost[rows]
    load = np.zeros(n_threads)
    members = [[] for _ in range(n_threads)]
    for r in rows[np.argsort(-c, kind="stable")]:
        t = int(np.argmin(load))
        members[t].append(r)
        load[t] += cost[r]
    order = np.array([r for m in members for r in m], dtype=np.int64)
    bins = np.concatenate([[0], np.cumsum([len(m) for m in members])]).astype(np.int64)
    return order, bins


def template_of(cell):
    """A DemCell without state arrays: law, options, time step and rotation mode of `cell`
    (DemCell.view gives it a state)."""
    return type(cell).view(cell, None)


def homogenized_outputs(cauchy, couple, fabric, counts, particles):
    """The values of homogenization.homogenize of many cells from their contact sums: Cauchy
    stress (n, 2, 2) [N/m], couple stress (n, 2), fabric (n, 2, 2), counts (n, 2) of contacts
    and sliding contacts, particles (n,). Adds the coordination number 2C/N, the anisotropy
    (000 eq. 38), the sliding fraction and the stress ratio (000 eq. 40)."""
    nc, nsl = counts[:, 0], counts[:, 1]
    w = np.linalg.eigvalsh(fabric) if len(fabric) else np.zeros((0, 2))
    anis = np.where(w[:, 0] > 0.0, w[:, 1] / np.where(w[:, 0] > 0.0, w[:, 0], 1.0) - 1.0, 0.0)
    den = np.abs(cauchy[:, 0, 0] + cauchy[:, 1, 1])
    ratio = np.where(den > 0.0, np.abs(cauchy[:, 0, 0] - cauchy[:, 1, 1]) / np.where(den > 0.0, den, 1.0), 0.0)
    return {"cauchy": cauchy, "couple_stress": couple, "fabric": fabric, "n_contacts": nc, "n_sliding": nsl,
            "coordination_number": 2.0 * nc / particles, "anisotropy": anis,
            "sliding_fraction": np.where(nc > 0, nsl / np.maximum(nc, 1), 0.0), "stress_ratio": ratio}


def demqo(store, rows, eps=1e-6):
    """DEMQO (001 eq. 20) of the cells rows of a store (CellBatch or gpu.DeviceCellBatch), batched: each cell's current state copied and
    frozen (contacts bilateral, no sliding, no new contacts), re-relaxed at its F with the
    tight options of tangent.perturbation_options, then copies of it perturbed by eps L^mn
    (and, in a micropolar cell, its curvature by eps / max|Y_k|) and relaxed, all copies of
    all cells in one call. Returns (list of tangents: 4x4 d sigma / d F in demcell's order,
    or the 6x6 micropolar operator in the callback's order, as DemCell.tangent('demqo')
    gives them; DEM steps per cell)."""
    from .network import CALLBACK_ROWS
    from .tangent import COMPONENTS, perturbation_options
    rows = np.asarray(rows, dtype=np.int64)
    n = len(rows)
    if not n:
        return [], np.zeros(0)
    base = store.subset(rows)
    for j, view in enumerate(store.views(rows)):
        o = perturbation_options(view, eps)          # numpy means, as a DemCell computes them
        view.freeze_contacts()
        base.law[j] = view.law_array
        base.opts[j] = qs.solve_options(o, o.skin(view.state.radius), o.max_steps)
    all_ = np.arange(n)
    F = base.deformation_gradients(all_)
    base.set_targets(all_, F, store.target[rows, slots.T_PHI], store.target[rows, slots.T_KAP:slots.T_KAP + 2])
    steps = base.solve(all_)[:, slots.R_STEPS].copy()
    h0 = base.homogenize(all_)
    micro = store.micropolar[rows]
    ncol = np.where(micro, 6, 4)
    owner = np.repeat(all_, ncol)
    column = np.concatenate([np.arange(m) for m in ncol])
    trials = base.subset(owner)
    Fp = F[owner].copy()
    kappa = trials.rotations(np.arange(len(owner)))[1]      # the base's kappa after its solve
    k_eps = eps / np.abs(base.lattices(all_)).sum(axis=1).max(axis=1)
    size = np.full(len(owner), float(eps))
    for t, (j, c) in enumerate(zip(owner, column)):
        if c < 4:
            Fp[t][COMPONENTS[c]] += eps
        else:
            kappa[t, c - 4] += k_eps[j]
            size[t] = k_eps[j]
    phi = base.target[owner, slots.T_PHI]
    kap_target = np.where(column[:, None] >= 4, kappa, base.target[owner, slots.T_KAP:slots.T_KAP + 2])
    trials.set_targets(np.arange(len(owner)), Fp, phi, kap_target)
    res = trials.solve(np.arange(len(owner)))
    np.add.at(steps, owner, res[:, slots.R_STEPS])
    h = trials.homogenize(np.arange(len(owner)))

    def flux(hom, i, micropolar):
        out = hom["cauchy"][i].reshape(4)
        return np.concatenate([out, hom["couple_stress"][i]]) if micropolar else out
    tangents = []
    for j in range(n):
        ref = flux(h0, j, micro[j])
        C = np.zeros((ref.size, ref.size))
        for t in np.flatnonzero(owner == j):
            C[:, column[t]] = (flux(h, t, micro[j]) - ref) / size[t]
        if micro[j]:
            order = list(CALLBACK_ROWS)
            C = C[np.ix_(order, order)]
        tangents.append(C)
    return tangents, steps


class CellStore:
    """What the stores of a rank's cells share: CellBatch (host memory, Numba threads) and
    gpu.DeviceCellBatch (resident on a CUDA device). Each cell's law, options, time step and
    target live here on the host; a store adds its state arrays and the methods that reach
    them (solve, homogenize, kruyt, rotations, lattices, contact_counts, subset, commit,
    rollback, state, committed_states, restore, views, nbytes)."""

    def _settings(self, cells):
        """Per-cell settings of DemCells `cells`: law, options as a solve row, time step,
        rotation mode, the target (their current F, phi, kappa)."""
        if not cells:
            raise InputError(f"{type(self).__name__} needs at least one cell")
        if not all(isinstance(c, DemCell) for c in cells):
            raise InputError(f"{type(self).__name__} takes DemCells")
        # law, options, time step, rotation mode of each cell (no state: the store holds it)
        self.templates = [template_of(c) for c in cells]
        n = len(cells)
        self.n_cells = n
        self.micropolar = np.array([c.micropolar for c in cells])
        self.law = np.array([c.law_array for c in cells])
        self.dt = np.array([c.dt for c in cells])
        self.opts = np.array([qs.solve_options(c.options, c.options.skin(c.state.radius),
                                               c.options.max_steps) for c in cells])
        self.max_steps = np.array([c.options.max_steps for c in cells], dtype=np.int64)
        self.target = np.zeros((n, slots.N_TARGET))
        self.cost = np.full(n, np.nan)    # DEM steps of each cell's last solve (nan: none yet)
        for k, c in enumerate(cells):
            self.target[k, slots.T_F:slots.T_F + 4] = c.state.F.reshape(4)
            self.target[k, slots.T_PHI] = c.state.phi
            self.target[k, slots.T_KAP:slots.T_KAP + 2] = c.state.kappa

    def rows_of(self, rows):
        """`rows` as an int64 array of cell indices in [0, n_cells), else InputError."""
        r = np.asarray(rows)
        if r.ndim != 1 or (r.size and (r.dtype.kind not in "iu" or r.min() < 0 or r.max() >= self.n_cells)):
            raise InputError(f"rows must be a 1D array of cell indices in [0, {self.n_cells}), got "
                             f"{checks.one_line(repr(rows))[:80]}")
        return r.astype(np.int64)

    def set_targets(self, rows, F, phi=None, kappa=None):
        """Targets of the cells rows: F (n, 2, 2) finite with det F > 0; for micropolar cells
        phi (n,) and kappa (n, 2), finite (None: the current ones)."""
        rows = self.rows_of(rows)
        n = len(rows)
        F = checks.array("F", F, (n, 2, 2))
        with np.errstate(over="ignore", invalid="ignore"):      # (refused below: det F not finite)
            det = np.linalg.det(F) if n else np.zeros(0)
        if not np.all((det > 0.0) & np.isfinite(det)):
            k = int(np.flatnonzero(~((det > 0.0) & np.isfinite(det)))[0])
            raise InputError(f"F must have a finite det F > 0 (an admissible deformation), got det F[{k}] = "
                             f"{det[k]:.3g}")
        phi = None if phi is None else checks.array("phi", phi, (n,))
        kappa = None if kappa is None else checks.array("kappa", kappa, (n, 2))
        self.target[rows, slots.T_F:slots.T_F + 4] = F.reshape(n, 4)
        phi_now, kappa_now = self.rotations(rows)
        self.target[rows, slots.T_PHI] = phi_now if phi is None else phi
        self.target[rows, slots.T_KAP:slots.T_KAP + 2] = kappa_now if kappa is None else kappa

    @staticmethod
    def substep_limit(max_steps):
        """The per-sub-step budget `max_steps` of solve (None, or an integer >= 1)."""
        max_steps = checks.optional("max_steps", max_steps, checks.COUNT)
        return None if max_steps is None else min(max_steps, checks.MAX_BUDGET)

    def solve_options(self, max_steps=None, method=None):
        """The option rows of a solve: each cell's own, with the per-sub-step budget
        `max_steps` and the relaxation `method` ('local' or 'fire') put in where given."""
        max_steps = self.substep_limit(max_steps)
        if method not in (None, "local", "fire"):
            raise checks.InputError(f"method must be 'local' or 'fire', got {method!r}")
        if max_steps is None and method is None:
            return self.opts
        opts = self.opts.copy()
        if max_steps is not None:
            opts[:, slots.Q_LIMIT] = max_steps
        if method is not None:
            opts[:, slots.Q_METHOD] = slots.FIRE if method == "fire" else slots.LOCAL_DAMPING
        return opts

    def outcome(self, k, result_row):
        """(converged, no_contacts, message, error) of cell k's solve (DemCell.solve's words;
        error: the text of a broken-down solve)."""
        converged, no_contacts, message, error = qs.outcome(result_row, self.dt[k])
        no_contacts, message = qs.final_words(converged, no_contacts, self.contact_count(k) if no_contacts else -1,
                                              [message], result_row[slots.R_MAXOVL])
        return converged, no_contacts, message, error

    def contact_count(self, k):
        return int(self.contact_counts([k])[0])

    def demqo(self, rows, eps=1e-6):
        """DEMQO (001 eq. 20) of the cells rows, batched (the module function ``demqo``)."""
        return demqo(self, rows, eps)

    def set_cell(self, k, template, state):
        """Cell k becomes `template`'s kind of cell (a DemCell: its law, options, time step and
        rotation mode are taken, not its state) continuing from `state` (a CellState of the
        same particle count)."""
        k = int(k)
        self.templates[k] = template_of(template)
        self.micropolar[k] = template.micropolar
        self.law[k] = template.law_array
        self.dt[k] = template.dt
        self.opts[k] = qs.solve_options(template.options, template.options.skin(state.radius),
                                        template.options.max_steps)
        self.max_steps[k] = template.options.max_steps
        self.restore(k, state)

    def view(self, k):
        """A DemCell of cell k (views into the store, or copies from a device: read it, solve
        through the store); its target is the store's."""
        return self.views([k])[0]

    def _target_of(self, k):
        """(F, phi, kappa) of cell k's target."""
        t = self.target[int(k)]
        return t[slots.T_F:slots.T_F + 4].reshape(2, 2), t[slots.T_PHI], t[slots.T_KAP:slots.T_KAP + 2]


class CellBatch(CellStore):
    """The cells of one rank (DemCells: each keeps its law, options and time step) in one
    struct of arrays. Methods take ``rows``, indices of the cells concerned."""

    def __init__(self, cells, rows=None):
        """cells: DemCells (their current and committed states are copied in); or a CellBatch
        whose cells `rows` (rows may repeat) are copied, current states only (current =
        committed), with their laws, options, time steps and targets (``subset``)."""
        if rows is not None:
            self._take_rows(cells, np.asarray(rows, dtype=np.int64))
            return
        cells = list(cells)
        self._settings(cells)
        np_ = np.array([c.state.n_particles for c in cells], dtype=np.int64)
        cap = np.array([max(c.state.pair_i.shape[0], c.committed_state.pair_i.shape[0]) for c in cells],
                       dtype=np.int64)
        self.p_off = np.concatenate([[0], np.cumsum(np_)]).astype(np.int64)
        self._first_state = cells[0].state
        self._layout(cap)
        self.current = self._empty()
        self.committed = self._empty()
        for k, c in enumerate(cells):
            self._put(self.current, k, c.state)
            self._put(self.committed, k, c.committed_state)
        del self._first_state

    def _take_rows(self, source, rows):
        """This batch made of copies of the current states of `source`'s cells rows."""
        self.n_cells = len(rows)
        self.templates = [source.templates[k] for k in rows]
        for name in ("micropolar", "law", "dt", "opts", "max_steps", "target", "cost"):
            setattr(self, name, getattr(source, name)[rows].copy())
        self.p_off = np.concatenate([[0], np.cumsum(np.diff(source.p_off)[rows])]).astype(np.int64)
        self._layout(source.capacity[rows])
        pidx, qidx = _ranges(source.p_off, rows), _ranges(source.q_off, rows)
        self.current = {name: source.current[name][pidx] for name in PARTICLE_FIELDS}
        self.current.update({name: source.current[name][qidx] for name in PAIR_FIELDS})
        self.current.update({name: source.current[name][rows] for name in ("h", "h_build", "h_ref", "cellf", "celli")})
        self.committed = {name: a.copy() for name, a in self.current.items()}

    # --- layout -------------------------------------------------------------------------------
    def _layout(self, capacity):
        self.capacity = np.asarray(capacity, dtype=np.int64)
        self.q_off = np.concatenate([[0], np.cumsum(self.capacity)]).astype(np.int64)

    def _empty(self):
        n, P, Q = self.n_cells, self.p_off[-1], self.q_off[-1]
        t = self._first_state
        store = {name: np.zeros((P,) + getattr(t, name).shape[1:], dtype=getattr(t, name).dtype)
                 for name in PARTICLE_FIELDS}
        store.update({name: np.zeros((Q,) + getattr(t, name).shape[1:], dtype=getattr(t, name).dtype)
                      for name in PAIR_FIELDS})
        store.update(h=np.zeros((n, 2, 2)), h_build=np.zeros((n, 2, 2)), h_ref=np.zeros((n, 2, 2)),
                     cellf=np.zeros((n, 4)), celli=np.zeros((n, 2), dtype=np.int64))
        return store

    def _put(self, store, k, st):
        p0, p1, q0 = self.p_off[k], self.p_off[k + 1], self.q_off[k]
        if st.n_particles != p1 - p0:
            raise InputError(f"cell {k}: a state of {st.n_particles} particles for {p1 - p0}")
        if st.pair_i.shape[0] > self.capacity[k]:
            self._grow(k, st.pair_i.shape[0])
        for name in PARTICLE_FIELDS:
            store[name][p0:p1] = getattr(st, name)
        m = st.pair_i.shape[0]
        for name in PAIR_FIELDS:
            store[name][q0:q0 + m] = getattr(st, name)
            store[name][q0 + m:self.q_off[k + 1]] = 0
        for name in ("h", "h_build", "h_ref"):
            store[name][k] = getattr(st, name)
        store["cellf"][k] = (st.time, st.phi, st.kappa[0], st.kappa[1])
        store["celli"][k] = (st.n_pairs, st.forces_current)

    def _get(self, store, k, copy=True):
        """The CellState of cell k in `store` (copies, or views into the store)."""
        p0, p1, q0, q1 = self.p_off[k], self.p_off[k + 1], self.q_off[k], self.q_off[k + 1]
        take = (lambda a: a.copy()) if copy else (lambda a: a)
        kw = {name: take(store[name][p0:p1]) for name in PARTICLE_FIELDS}
        kw.update({name: take(store[name][q0:q1]) for name in PAIR_FIELDS})
        kw.update({name: take(store[name][k]) for name in ("h", "h_build", "h_ref")})
        f, i = store["cellf"][k], store["celli"][k]
        return CellState(**kw, n_pairs=int(i[0]), forces_current=int(i[1]), time=float(f[0]), phi=float(f[1]),
                         kappa=f[2:4].copy())

    def _grow(self, k, capacity):
        """Enlarge the pair slots of cell k to `capacity` in both stores (the other cells move)."""
        old_off = self.q_off
        new_cap = self.capacity.copy()
        new_cap[k] = capacity
        self._layout(new_cap)
        for store in (getattr(self, "current", None), getattr(self, "committed", None)):
            if store is None:
                continue
            for name in PAIR_FIELDS:
                old = store[name]
                new = np.zeros((self.q_off[-1],) + old.shape[1:], dtype=old.dtype)
                for c in range(self.n_cells):
                    m = old_off[c + 1] - old_off[c]
                    new[self.q_off[c]:self.q_off[c] + m] = old[old_off[c]:old_off[c + 1]]
                store[name] = new

    # --- the work -------------------------------------------------------------------------------
    def _scan(self, rows, committed):
        store = self.committed if committed else self.current
        rows = np.asarray(rows, dtype=np.int64)
        F, counts = np.zeros((len(rows), 2, 2)), np.zeros(len(rows), dtype=np.int64)
        _gradients_and_counts(rows, self.q_off, store["h"], store["h_ref"], store["touching"], store["celli"], F, counts)
        return F, counts

    def deformation_gradients(self, rows, committed=False):
        """F = h h_ref^-1 of the cells rows (n, 2, 2)."""
        return self._scan(rows, committed)[0]

    def contact_counts(self, rows):
        """Touching contacts of the cells rows (current state)."""
        return self._scan(rows, False)[1]

    def solve(self, rows, max_steps=None, method=None):
        """Solve the cells rows from their current states to their targets (DemCell.solve
        without servo). Returns the result rows (len(rows), quasistatic.N_RESULT); read them
        with ``outcome``. max_steps: the budget per sub-step after the ramp (default: each
        cell's options), DemCell.solve's max_substep_steps; each cell's whole solve is bounded
        by its options' solve_budget. method: 'local' or 'fire' for this solve (default:
        each cell's options)."""
        rows = self.rows_of(rows)
        opts = self.solve_options(max_steps, method)
        result = np.zeros((self.n_cells, slots.N_RESULT))
        if not len(rows):
            return result[rows]
        work = np.zeros((self.n_cells, slots.N_WORK))
        iwork = np.zeros((self.n_cells, slots.N_IWORK), dtype=np.int64)
        code = np.ones(self.n_cells, dtype=np.int64)
        code[rows] = 0
        order, bins = _bins(rows, self.cost, get_num_threads())
        while True:
            cur = self.current
            _solve_rows(order, bins, self.p_off, self.q_off, cur["radius"], cur["mass"], cur["inertia"], cur["s"],
                        cur["v"], cur["theta"], cur["omega"], cur["dtheta"], cur["force"], cur["moment"],
                        cur["s_build"], cur["h"], cur["h_build"], cur["h_ref"], cur["pair_i"], cur["pair_j"],
                        cur["fn"], cur["fs"], cur["mr"], cur["bonded"], cur["touching"], cur["d_prev"],
                        cur["cellf"], cur["celli"], self.law, self.dt, opts, self.target, work, iwork, result, code)
            full = np.flatnonzero(code == 2)
            if not len(full):
                break
            # pair arrays full: double them (as relaxation.run) and resume those cells
            for c in full:
                self._grow(c, 2 * self.capacity[c])
            code[:] = 1
            code[full] = 0
            order, bins = _bins(full, self.cost, get_num_threads())
        self.cost[rows] = np.maximum(result[rows, slots.R_STEPS], 1.0)
        return result[rows]

    def homogenize(self, rows):
        """Cauchy stress (n, 2, 2) [N/m], couple stress (n, 2), fabric (n, 2, 2), contacts,
        sliding contacts, coordination number 2C/N, anisotropy (000 eq. 38), sliding fraction
        and stress ratio (000 eq. 40) of the cells rows: the values of homogenization.homogenize."""
        rows = np.asarray(rows, dtype=np.int64)
        n = len(rows)
        cur = self.current
        cauchy, couple, fabric = np.zeros((n, 2, 2)), np.zeros((n, 2)), np.zeros((n, 2, 2))
        counts = np.zeros((n, 2), dtype=np.int64)
        for flag in (False, True):
            sel = rows[self.micropolar[rows] == flag]
            if len(sel):
                idx = np.flatnonzero(self.micropolar[rows] == flag)
                c_, m_, f_, n_ = np.zeros((len(sel), 2, 2)), np.zeros((len(sel), 2)), np.zeros((len(sel), 2, 2)), \
                    np.zeros((len(sel), 2), dtype=np.int64)
                _homogenize_rows(sel, self.p_off, self.q_off, cur["h"], cur["s"], cur["radius"], cur["pair_i"],
                                 cur["pair_j"], cur["fn"], cur["fs"], cur["mr"], cur["touching"], cur["celli"],
                                 self.law, cur["h_ref"], flag, c_, m_, f_, n_)
                cauchy[idx], couple[idx], fabric[idx], counts[idx] = c_, m_, f_, n_
        return homogenized_outputs(cauchy, couple, fabric, counts, np.diff(self.p_off)[rows])

    def kruyt(self, rows):
        """Kruyt operators (001 eq. 13) of the cells rows, (n, 4, 4) d sigma / d F in demcell's order."""
        rows = np.asarray(rows, dtype=np.int64)
        cur = self.current
        T = np.zeros((len(rows), 2, 2, 2, 2))
        _kruyt_rows(rows, self.p_off, self.q_off, cur["h"], cur["h_ref"], cur["s"], cur["pair_i"], cur["pair_j"],
                    cur["touching"], cur["celli"], self.law, T)
        return T.reshape(len(rows), 4, 4)

    def rotations(self, rows, committed=False):
        """(phi (n,) [rad], kappa (n, 2) [1/m]) of the cells rows (micropolar cells; 0 else)."""
        cf = (self.committed if committed else self.current)["cellf"][np.asarray(rows, dtype=np.int64)]
        return cf[:, 1].copy(), cf[:, 2:4].copy()

    def lattices(self, rows, committed=False):
        """h_ref (n, 2, 2) [m] of the cells rows: the reference cell, which a lattice reduction
        changes (F = h h_ref^-1 does not)."""
        return (self.committed if committed else self.current)["h_ref"][np.asarray(rows, dtype=np.int64)].copy()

    def subset(self, rows):
        """A new CellBatch of copies of the current states of rows (current = committed),
        with their laws, options, time steps and targets; rows may repeat."""
        return CellBatch(self, rows)

    # --- state ------------------------------------------------------------------------------------
    def _copy(self, rows, src, dst):
        rows = np.asarray(rows, dtype=np.int64)
        if not len(rows):
            return
        pidx, qidx = _ranges(self.p_off, rows), _ranges(self.q_off, rows)
        for name in PARTICLE_FIELDS:
            dst[name][pidx] = src[name][pidx]
        for name in PAIR_FIELDS:
            dst[name][qidx] = src[name][qidx]
        for name in ("h", "h_build", "h_ref", "cellf", "celli"):
            dst[name][rows] = src[name][rows]

    def commit(self, rows):
        """The current states of rows become their committed states."""
        self._copy(rows, self.current, self.committed)

    def rollback(self, rows):
        """Cells rows return to their committed states (targets: the committed F, phi, kappa)."""
        rows = np.asarray(rows, dtype=np.int64)
        self._copy(rows, self.committed, self.current)
        if len(rows):
            self.set_targets(rows, self.deformation_gradients(rows))

    def committed_states(self, rows):
        """Copies of the committed CellStates of rows (what a checkpoint saves)."""
        return [self._get(self.committed, int(k)) for k in rows]

    def restore(self, k, state):
        """Cell k continues from `state` (a CellState): committed and current."""
        self._put(self.committed, int(k), state)
        self._put(self.current, int(k), state)
        self.rollback([int(k)])

    def state(self, k):
        """A copy of the current CellState of cell k."""
        return self._get(self.current, int(k))

    def views(self, rows):
        """DemCells of the cells rows whose state arrays are views into the store (read them:
        their tangents, homogenized outputs; solve through the batch, not through a view)."""
        return [DemCell.view(self.templates[int(k)], self._get(self.current, int(k), copy=False),
                             self._get(self.committed, int(k), copy=False), self._target_of(k)) for k in rows]

    def nbytes(self):
        """Bytes of both stores."""
        return sum(a.nbytes for store in (self.current, self.committed) for a in store.values())
