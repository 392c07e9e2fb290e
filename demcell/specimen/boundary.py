"""The free lateral sides of a bounded disc specimen: boundary loop, pressure arcs, membrane.

Thesis 004 sec. 7.3.2 confines the left and right sides of its biaxial specimen by a pressure
p acting on the outside arcs of the boundary discs (004 eq. 7.44) and a membrane that pulls
consecutive boundary discs together when a gap opens between them (004 eqs. 7.45-7.46). The
chain of boundary discs is found again every few steps, so that the sides may bulge freely.

Conventions: 2D, per unit out-of-plane depth. Lengths m, forces N (per m of depth), the
pressure p and the membrane stiffness E_m in N/m (a stress N/m^2 times the unit depth).
p > 0 is a confining (compressive) pressure: the confining stress is -p, tension positive.
x horizontal, y vertical; counter-clockwise (CCW) is the positive sense of rotation.

The steps, each a pure function over arrays:
  1. ``boundary_loop``: the outer boundary loop of the largest connected component of the
     proximity graph (edge i-j when |x_i - x_j| <= r_i + r_j + g), ordered CCW, found by the
     right-hand walk of the spec's fallback (no Delaunay triangulation needed). O(n + m).
  2. ``side_chains``: the loop cut at the platen-contact discs ("edge particles") into the
     right side (bottom -> top) and the left side (top -> bottom), each chain ending at the
     two platen-contact discs next to it, its anchors.
  3. ``pressure_forces`` (004 eq. 7.44) and 4. ``membrane_forces`` (004 eqs. 7.45-7.46):
     Numba kernels that ADD the forces of the chains into a force array, every step.
  5. ``escaped_discs``: discs whose centre lies outside the loop polygon (pushed through the
     membrane, or flown off).

Chains are stored flat: side c is ``chain[chain_start[c]:chain_start[c + 1]]``, in CCW loop
order, its first and last entries being its anchors (platen-contact discs: no pressure, but
they bound the outside arcs of the end discs and hold the ends of the membrane).
"""
import math

import numpy as np
from numba import njit

from ..checks import NON_NEGATIVE, number
from ..errors import InputError, SolveError

#: right side first (bottom -> top), then the left side (top -> bottom), in chain_start order
RIGHT, LEFT = 0, 1

_TWO_PI = 2.0 * math.pi


# ---------------------------------------------------------------------------------------------
# 1. boundary loop
# ---------------------------------------------------------------------------------------------

@njit(cache=True)
def _find(parent, i):
    # union-find root with path halving
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@njit(cache=True)
def _next_ccw(i, back_angle, came_from, start, adj, adj_dx, adj_dy):
    """The neighbour of i met first when sweeping CCW from the direction `back_angle`; the
    neighbour `came_from` (the disc the walk arrived from) only if i has no other neighbour
    (a dangling end: the walk turns back). Returns the half-edge index into adj."""
    best = -1
    best_delta = 10.0 * _TWO_PI
    for e in range(start[i], start[i + 1]):
        k = adj[e]
        if k == came_from:
            delta = _TWO_PI + 1.0      # after every other neighbour
        else:
            delta = math.atan2(adj_dy[e], adj_dx[e]) - back_angle
            delta -= _TWO_PI * math.floor(delta / _TWO_PI)
            if delta <= 0.0:           # same direction as the arrival: swept last
                delta = _TWO_PI
        if delta < best_delta:
            best_delta = delta
            best = e
    return best


@njit(cache=True)
def _boundary_loop(position, radius, pair_i, pair_j, gap_tolerance, width):
    """Kernel of ``boundary_loop``: (loop, status); status 0 done, 1 step cap exceeded."""
    n = position.shape[0]
    m = pair_i.shape[0]
    keep = np.zeros(m, np.bool_)
    degree = np.zeros(n + 1, np.int64)
    n_edges = 0
    for e in range(m):
        i = pair_i[e]
        j = pair_j[e]
        if i == j:
            continue
        dx = position[j, 0] - position[i, 0]
        if width > 0.0:
            dx -= width * math.floor(dx / width + 0.5)
        dy = position[j, 1] - position[i, 1]
        reach = radius[i] + radius[j] + gap_tolerance
        if dx * dx + dy * dy <= reach * reach:
            keep[e] = True
            degree[i + 1] += 1
            degree[j + 1] += 1
            n_edges += 1
    start = np.cumsum(degree)
    fill = start[:-1].copy()
    adj = np.empty(2 * n_edges, np.int64)
    adj_dx = np.empty(2 * n_edges)
    adj_dy = np.empty(2 * n_edges)
    parent = np.arange(n)
    for e in range(m):
        if not keep[e]:
            continue
        i = pair_i[e]
        j = pair_j[e]
        dx = position[j, 0] - position[i, 0]
        if width > 0.0:
            dx -= width * math.floor(dx / width + 0.5)
        dy = position[j, 1] - position[i, 1]
        adj[fill[i]] = j
        adj_dx[fill[i]] = dx
        adj_dy[fill[i]] = dy
        fill[i] += 1
        adj[fill[j]] = i
        adj_dx[fill[j]] = -dx
        adj_dy[fill[j]] = -dy
        fill[j] += 1
        ri = _find(parent, i)
        rj = _find(parent, j)
        if ri != rj:
            parent[max(ri, rj)] = min(ri, rj)
    # the largest component (the lowest root among equals: deterministic)
    size = np.zeros(n, np.int64)
    for i in range(n):
        size[_find(parent, i)] += 1
    root = 0
    for i in range(n):
        if size[i] > size[root]:
            root = i
    # start: its lowest disc (then leftmost), surely on the outer boundary with the
    # exterior straight below it
    s = -1
    for i in range(n):
        if _find(parent, i) == root:
            if s < 0 or position[i, 1] < position[s, 1] or (
                    position[i, 1] == position[s, 1] and position[i, 0] < position[s, 0]):
                s = i
    loop = np.empty(2 * n_edges + 1, np.int64)
    loop[0] = s
    if start[s + 1] == start[s]:
        return loop[:1], 0
    # as if arrived from straight below: the first edge CCW from -y is on the outer boundary
    first = _next_ccw(s, -0.5 * math.pi, -1, start, adj, adj_dx, adj_dy)
    e = first
    cur = s
    count = 1
    # the walk follows a permutation of the 2 n_edges half-edges: it comes back to the first
    # one within 2 n_edges steps; the cap only guards against a broken neighbour order
    while count <= 2 * n_edges:
        nxt = adj[e]
        back = math.atan2(-adj_dy[e], -adj_dx[e])
        e = _next_ccw(nxt, back, cur, start, adj, adj_dx, adj_dy)
        cur = nxt
        if cur == s and e == first:
            return loop[:count], 0
        loop[count] = cur
        count += 1
    return loop[:count], 1


def _check_pairs(position, radius, pair_i, pair_j):
    n = position.shape[0]
    pair_i = np.ascontiguousarray(pair_i, dtype=np.int64)
    pair_j = np.ascontiguousarray(pair_j, dtype=np.int64)
    if pair_i.ndim != 1 or pair_i.shape != pair_j.shape:
        raise InputError(f"pair_i and pair_j must be 1-d arrays of one length, got shapes "
                         f"{pair_i.shape} and {pair_j.shape}")
    if pair_i.size and (min(pair_i.min(), pair_j.min()) < 0 or max(pair_i.max(), pair_j.max()) >= n):
        raise InputError(f"pair_i and pair_j must be disc indices in [0, {n - 1}]")
    return pair_i, pair_j


def _check_discs(position, radius):
    position = np.ascontiguousarray(position, dtype=np.float64)
    if position.ndim != 2 or position.shape[1] != 2 or position.shape[0] == 0:
        raise InputError(f"position must be an array of shape (n, 2) with n >= 1, got shape {position.shape}")
    if not np.isfinite(position).all():
        raise InputError("position must be finite, got a nan or inf")
    radius = np.ascontiguousarray(radius, dtype=np.float64)
    if radius.shape != (position.shape[0],):
        raise InputError(f"radius must be an array of shape ({position.shape[0]},), got shape {radius.shape}")
    if not (radius > 0.0).all() or not np.isfinite(radius).all():
        raise InputError("radius must be finite and > 0")
    return position, radius


def boundary_loop(position, radius, pair_i, pair_j, gap_tolerance, periodic_width=0.0):
    """The outer boundary loop of the specimen, as disc indices ordered counter-clockwise.

    The proximity graph links discs i, j of a candidate pair (pair_i[k], pair_j[k]) when
    |x_i - x_j| <= r_i + r_j + gap_tolerance (dns-spec A6: g_tol = 0.5 r by default). Its
    largest connected component is walked by the right-hand rule (dns-spec A6, step 6): start
    at the component's lowest disc (the leftmost among equals), leave it by the first edge
    met sweeping CCW from straight down, then at each disc i arrived at from h take the first
    neighbour met sweeping CCW from the direction i -> h (h itself only at a dead end). The
    walk stops when its first directed edge comes again. On a planar graph (no crossing edges,
    true for equal discs with g < 0.83 r) this is the outer face, the exterior on the right.

    Parameters: position (n, 2) [m] centres; radius (n,) [m]; pair_i, pair_j (m,) int
    candidate pairs (the Verlet list: its skin must be >= gap_tolerance, else edges are lost;
    with skin == gap_tolerance a pair that closes in between two list rebuilds is missed until
    the next rebuild, which may move the loop by one disc for that while);
    gap_tolerance [m] >= 0; periodic_width [m]: 0 for a bounded specimen, else the period in x
    (minimum-image edges; the loop is then the lower surface of the strip walked over one
    period in +x, since the start disc has the exterior below it).

    Returns an int64 array L. loop[0] is the start disc; the loop closes from L[-1] back to
    L[0]. Discs outside the largest component never appear, nor do holes inside it. A disc
    appears more than once where the loop passes it more than once: a dangling chain (a line
    of discs sticking out) is walked out and back, so each of its discs but the tip appears
    twice and the disc it hangs from too; likewise a disc joining two lobes. A component of
    one disc gives [that disc]; of two discs i-j gives [i, j].

    Cost: O(n + m) (one pass over the pairs, a union-find, a walk over the boundary).
    """
    position, radius = _check_discs(position, radius)
    pair_i, pair_j = _check_pairs(position, radius, pair_i, pair_j)
    gap_tolerance = number("gap_tolerance", gap_tolerance, NON_NEGATIVE)
    periodic_width = number("periodic_width", periodic_width, NON_NEGATIVE)
    loop, status = _boundary_loop(position, radius, pair_i, pair_j, gap_tolerance, periodic_width)
    if status:
        raise SolveError(f"the boundary walk did not close within {len(loop)} steps "
                         f"(inconsistent neighbour order: coincident or crossing discs?)")
    return loop


# ---------------------------------------------------------------------------------------------
# 2. side chains
# ---------------------------------------------------------------------------------------------

def side_chains(loop, on_wall, position=None):
    """The right and left free sides of the loop, cut at the platen-contact discs.

    dns-spec A6 steps 3-5: the loop discs touching a platen ("edge particles", on_wall != 0)
    are removed; the remaining runs of consecutive loop discs are open chains. The right side
    is walked bottom -> top and the left side top -> bottom (both in the loop's CCW order).
    Each chain keeps the platen-contact disc just before and just after it as its anchors:
    they get no pressure, but bound the outside arc of the end discs and hold the membrane.

    Which runs are the sides: with `position` (recommended), the right side is the run that
    climbs most from its first anchor to its last (y_end - y_start > 0) and the left side the
    one that descends most (< 0); short runs of discs along a platen that do not touch it are
    neither and get no load. Without `position`, the two longest runs, the first met after
    loop[0] (the lowest disc, on the bottom platen) being the right side.

    Parameters: loop (L,) int disc indices in CCW order (``boundary_loop``); on_wall (n,)
    flags, nonzero for a disc touching a platen; position (n, 2) [m] optional.

    Returns (chain, chain_start), int64: side c in {RIGHT = 0, LEFT = 1} is
    chain[chain_start[c]:chain_start[c + 1]], anchors included (its first and last entries),
    so a side with k free discs has k + 2 entries and an absent side has none
    (chain_start[c] == chain_start[c + 1]). Raises InputError when no loop disc touches a
    platen (the sides cannot be told apart).
    """
    loop = np.asarray(loop, dtype=np.int64)
    on_wall = np.asarray(on_wall)
    if loop.ndim != 1 or loop.size == 0:
        raise InputError(f"loop must be a non-empty 1-d array of disc indices, got shape {loop.shape}")
    if loop.min() < 0 or loop.max() >= on_wall.shape[0]:
        raise InputError(f"loop must hold disc indices in [0, {on_wall.shape[0] - 1}]")
    wall = on_wall[loop] != 0
    if not wall.any():
        raise InputError("no disc of the boundary loop touches a platen: the free sides have no anchors")
    k0 = int(np.argmax(wall))
    seq = np.concatenate([np.roll(loop, -k0), loop[k0:k0 + 1]])  # closed: wall ... wall
    free = ~np.concatenate([np.roll(wall, -k0), wall[k0:k0 + 1]])
    # runs of free entries [a, b) with the anchors seq[a - 1], seq[b]
    edges = np.diff(free.astype(np.int8))
    starts = np.flatnonzero(edges == 1) + 1
    ends = np.flatnonzero(edges == -1) + 1
    runs = [seq[a - 1:b + 1] for a, b in zip(starts, ends)]
    right = left = None
    if position is not None:
        position = np.asarray(position, dtype=np.float64)
        if position.ndim != 2 or position.shape != (on_wall.shape[0], 2):
            raise InputError(f"position must be an array of shape ({on_wall.shape[0]}, 2), got shape {position.shape}")
        rise = [position[r[-1], 1] - position[r[0], 1] for r in runs]
        if runs:
            k = int(np.argmax(rise))
            right = runs[k] if rise[k] > 0 else None
            k = int(np.argmin(rise))
            left = runs[k] if rise[k] < 0 else None
    elif runs:
        longest = sorted(sorted(range(len(runs)), key=lambda k: -len(runs[k]))[:2])
        # the loop was turned to start at its first wall disc: the order of the runs is the
        # order after loop[0]
        right = runs[longest[0]]
        left = runs[longest[1]] if len(longest) > 1 else None
    parts = [np.empty(0, np.int64) if r is None else r for r in (right, left)]
    chain_start = np.array([0, len(parts[0]), len(parts[0]) + len(parts[1])], dtype=np.int64)
    return np.ascontiguousarray(np.concatenate(parts), dtype=np.int64), chain_start


# ---------------------------------------------------------------------------------------------
# 3-4. pressure arcs and membrane (every step)
# ---------------------------------------------------------------------------------------------

@njit(cache=True)
def pressure_forces(position, radius, chain, chain_start, pressure, out, anchors=True):
    """Confining pressure on the outside arcs of the free boundary discs, 004 eq. 7.44.

    f_press^(i) = -p int_{dP_out} n ds over the outside arc of disc i, bounded by the
    directions a = dir(x_prev - x_i) and b = dir(x_next - x_i) to its neighbours on the chain
    and swept CCW from a to b over the exterior (chains run CCW, the exterior on the right).
    Closed form (dns-spec A6), exact for a circular arc:
        f_press^(i) = -p r_i (sin th_b - sin th_a, cos th_a - cos th_b)
                    = -p r_i (nu_(prev,i) + nu_(i,next)),
    nu the outward unit normal of a centre segment: the pressure on the half-segments of
    length r_i inside disc i; a gap between discs carries no load. A disc met twice (the tip
    of a dangling chain: prev == next) gets the full circle, zero.

    The anchors (the platen-contact discs at the ends of a chain, 004's "edge particles"):
    with anchors=True (default) each gets the pressure on its lateral arc, from the direction
    of its platen (straight down at the bottom, up at the top) to its chain neighbour, so the
    confining pressure acts over the whole height between the platens. With anchors=False (the
    literal reading of 004 section 7.3.2, dns-spec A6 5.) they get none; then nothing holds the
    platen rows laterally but friction, and on smooth platens (004) the corner discs of a
    lattice creep outwards under the isotropic stage: measured on a 10 x 20 lattice at
    p = 50 N/m, the width grew by 3 % in 120 s and the platen stress never settled within
    1e-3 p.

    position (n, 2) [m]; radius (n,) [m]; chain, chain_start int64 (``side_chains``: the first
    and last entries of each chain are its anchors); pressure p [N/m], > 0 confining; out
    (n, 2) [N]: the forces are ADDED to it; anchors: load the anchors' lateral arcs.

    Returns totals (n_chains, 2) [N]: the sum of the pressure forces per chain (for a straight
    touching side, |total_x| = p x the height between its anchors' centres, within 2 p r).
    """
    n_chains = chain_start.shape[0] - 1
    totals = np.zeros((n_chains, 2))
    for c in range(n_chains):
        first = chain_start[c]
        last = chain_start[c + 1] - 1
        if last <= first:
            continue
        # the platens lie beyond the ends: below the lower end of the chain, above the upper
        down = 1.0 if position[chain[first], 1] > position[chain[last], 1] else -1.0
        lo = first if anchors else first + 1
        hi = last if anchors else last - 1
        for k in range(lo, hi + 1):
            i = chain[k]
            if k == first:          # the first anchor: from its platen's direction
                ax = 0.0
                ay = down
            else:
                a = chain[k - 1]
                ax = position[a, 0] - position[i, 0]
                ay = position[a, 1] - position[i, 1]
            if k == last:           # the last anchor: to its platen's direction
                bx = 0.0
                by = -down
            else:
                b = chain[k + 1]
                bx = position[b, 0] - position[i, 0]
                by = position[b, 1] - position[i, 1]
            la = math.sqrt(ax * ax + ay * ay)
            lb = math.sqrt(bx * bx + by * by)
            # cos th = dx / l, sin th = dy / l; a coincident neighbour bounds nothing
            if la > 0.0:
                ax /= la
                ay /= la
            if lb > 0.0:
                bx /= lb
                by /= lb
            fx = -pressure * radius[i] * (by - ay)
            fy = -pressure * radius[i] * (ax - bx)
            out[i, 0] += fx
            out[i, 1] += fy
            totals[c, 0] += fx
            totals[c, 1] += fy
    return totals


@njit(cache=True)
def membrane_forces(position, radius, chain, chain_start, stiffness, out):
    """Membrane between consecutive chain discs, anchors included, 004 eqs. 7.45-7.46.

    f_m^(i,i+1) = E_m <|x_i - x_(i+1)| - r_i - r_(i+1)> n^(i,i+1), n^(i,i+1) the unit vector
    from i to i+1, <.> the positive part: attraction only, when a gap opens between the
    discs; zero while they touch or overlap. The force on i+1 is its opposite (no moment).
    With the pressure force, the total force on a lateral disc is 7.46:
    f_mp^(i) = f_press^(i) + f_m^(i,i+1) + f_m^(i,i-1).

    position (n, 2) [m]; radius (n,) [m]; chain, chain_start int64 (``side_chains``);
    stiffness E_m [N/m]; out (n, 2) [N]: the forces are ADDED to it.

    Returns tension (n_chains,) [N]: the sum over each chain's segments of the membrane
    force magnitudes E_m <gap> (zero while the chain is closed).
    """
    n_chains = chain_start.shape[0] - 1
    tension = np.zeros(n_chains)
    for c in range(n_chains):
        for k in range(chain_start[c], chain_start[c + 1] - 1):
            i = chain[k]
            j = chain[k + 1]
            dx = position[j, 0] - position[i, 0]
            dy = position[j, 1] - position[i, 1]
            dist = math.sqrt(dx * dx + dy * dy)
            gap = dist - radius[i] - radius[j]
            if gap > 0.0:
                f = stiffness * gap / dist
                out[i, 0] += f * dx
                out[i, 1] += f * dy
                out[j, 0] -= f * dx
                out[j, 1] -= f * dy
                tension[c] += stiffness * gap
    return tension


# ---------------------------------------------------------------------------------------------
# 5. escaped discs
# ---------------------------------------------------------------------------------------------

@njit(cache=True)
def _outside_polygon(position, loop):
    """Flags (n,) of the centres outside the closed polygon through position[loop] (even-odd
    rule, a horizontal ray to +x). The polygon's edges are binned in horizontal strips so that
    each point meets only the edges of its strip: O(n + L) for a compact loop."""
    n = position.shape[0]
    n_loop = loop.shape[0]
    outside = np.ones(n, np.bool_)
    if n_loop < 3:
        return outside
    y_min = position[loop[0], 1]
    y_max = y_min
    for k in range(n_loop):
        y = position[loop[k], 1]
        y_min = min(y_min, y)
        y_max = max(y_max, y)
    n_strips = n_loop
    height = (y_max - y_min) / n_strips
    if height <= 0.0:
        return outside
    count = np.zeros(n_strips + 1, np.int64)
    for k in range(n_loop):
        y0 = position[loop[k], 1]
        y1 = position[loop[(k + 1) % n_loop], 1]
        s0 = min(int((min(y0, y1) - y_min) / height), n_strips - 1)
        s1 = min(int((max(y0, y1) - y_min) / height), n_strips - 1)
        for s in range(s0, s1 + 1):
            count[s + 1] += 1
    start = np.cumsum(count)
    fill = start[:-1].copy()
    strip_edges = np.empty(start[-1], np.int64)
    for k in range(n_loop):
        y0 = position[loop[k], 1]
        y1 = position[loop[(k + 1) % n_loop], 1]
        s0 = min(int((min(y0, y1) - y_min) / height), n_strips - 1)
        s1 = min(int((max(y0, y1) - y_min) / height), n_strips - 1)
        for s in range(s0, s1 + 1):
            strip_edges[fill[s]] = k
            fill[s] += 1
    for p in range(n):
        x = position[p, 0]
        y = position[p, 1]
        if y < y_min or y > y_max:
            continue
        s = min(int((y - y_min) / height), n_strips - 1)
        inside = False
        for q in range(start[s], start[s + 1]):
            k = strip_edges[q]
            x0 = position[loop[k], 0]
            y0 = position[loop[k], 1]
            x1 = position[loop[(k + 1) % n_loop], 0]
            y1 = position[loop[(k + 1) % n_loop], 1]
            # half-open in y: an edge counts once at a shared vertex, a horizontal never
            if (y0 > y) != (y1 > y):
                if x < x0 + (y - y0) * (x1 - x0) / (y1 - y0):
                    inside = not inside
        outside[p] = not inside
    return outside


def escaped_discs(position, radius, loop):
    """Indices (int64, ascending) of the discs whose centre lies outside the polygon through
    the centres of the loop discs (even-odd rule): grains pushed through the membrane, or
    discs no longer connected to the specimen that lie outside it. The loop's own discs are
    never listed (their centres are its vertices); discs in a hole of the specimen are
    inside. position (n, 2) [m]; radius (n,) [m] (checked only: the test is on centres);
    loop (L,) int from ``boundary_loop`` (not for a periodic strip)."""
    position, radius = _check_discs(position, radius)
    loop = np.ascontiguousarray(loop, dtype=np.int64)
    if loop.ndim != 1 or loop.size == 0 or loop.min() < 0 or loop.max() >= position.shape[0]:
        raise InputError(f"loop must be a non-empty 1-d array of disc indices in [0, {position.shape[0] - 1}]")
    outside = _outside_polygon(position, loop)
    outside[loop] = False
    return np.flatnonzero(outside).astype(np.int64)
