"""Load balancing of Gauss points whose cost varies (FEM x DEM): points move between ranks.

The mesh partition gives every rank the same number of Gauss points, but in FEM x DEM a
point's work is its cell's relaxation, and the cells in a band relax far longer than those
outside it: a rank holding the band finishes its cells late and the others wait for it at
the next collective (the assembly). `BalancedMaterial` wraps a material and lets another
rank work on a point: the partition's points of a rank are its *home* points (the
Gauss-point store keeps their float history, fluxes and tangents), and each home point has
one *worker* rank whose inner material holds its resident state (the DEM cell) in a *slot*.
Initially every point is worked on at home; the float history never moves, only the
resident state does.

Per call (every rank, every time: `collective = True`, the Gauss-point store then
calls even a rank with nothing to update):

    update   home -> worker: point index, gradients, committed history row   (Alltoallv)
             worker: the inner material updates its slots, one point per call (timed)
             worker -> home: fluxes, trial history row, [tangent], status, cost (Alltoallv)
    tangent  home -> worker: point index; worker -> home: tangent, status, cost
    messages (the first failure / flag of each home rank's points, named by the worker's
             inner material with the point's coordinates) go back with comm.alltoall

Failures stay local until the exchange is complete: the inner material's ConstitutiveError
becomes a failed status with its message (the store raises it on the home rank after the
material returned, the solver makes it collective), any other exception of the inner
material is carried back as a fatal error and raised (RuntimeError) on the home ranks of
the points of that call, again only after every exchange of the call.

Balancing (after a commit, every `every` commits, when the measured imbalance exceeds
`threshold`; with `passes=True` instead at the start of every Newton pass, by the costs of
the pass before, see below): the cost of a point is the wall time its worker spent in the
inner material's update and tangent for it since the previous commit (`cost='wall'`, the default: the DEM
time steps a cell reports leave out the tangent's work, e.g. pstlo's linear solve, and the
cost of a step grows with the contacts: the seconds per DEM step of the points spread by a
factor 2.5, docs/results/balancing.md; `cost='work'` uses the reported cost instead). The
per-point costs are gathered on every rank and `assign` (deterministic, the same on every
rank) moves points from the most to the least loaded rank, each time the one whose move
best evens the pair (cost nearest half the gap: the heaviest point that does not overshoot),
until the predicted slowest / mean is below the threshold. The moved points' resident state
goes with `export_points` / `import_points` (comm.alltoall of the struct-of-arrays dicts)
and every rank rebuilds its inner material (`make_material()`) with its new slots, the kept
ones exported and imported too (a restored cell continues bit for bit). The results do not
depend on where a point is worked on (tests/test_balancing.py); the imbalance is recorded
per commit (`balance_report`).

Between Newton passes (`passes=True`): the cells of the band cost more in some passes of a
step than in others, and a balance made after the commit acts one step late. With this
option the wrapper measures the imbalance of every pass (its update and tangent calls) and,
at the start of the next update, moves points by that pass's costs; the commit only
measures. A pass may move points only when every rank re-solves all its points in that
update, or none was solved since the last commit or rollback: every update of a point
starts its cell from the committed state (DemMaterial, 001 eq. 7), so the committed state
is all that has to move, but a point left out of the update keeps a trial state that a move
would lose.

On one rank the wrapper is a pass-through (no exchange, no balancing).

Modules: assignment.py (imbalance, assign), exchange.py (the protocol of one call: send,
work, reply, with named records and the STATUS_FATAL of a bug), migration.py (moving
resident state, rebuilding the inner material), material.py (BalancedMaterial).

export_points / import_points of the wrapper are collective (the home rank asks the
worker); the exported dict of the inner material must be a struct of arrays whose per-key
concatenation along axis 0 is the export of the concatenated points (true of
DemMaterial's pack_states + zone).
"""
from .assignment import DEFAULT_THRESHOLD, assign, imbalance
from .exchange import STATUS_FAILED, STATUS_FATAL
from .material import COSTS, BalancedMaterial

__all__ = ["BalancedMaterial", "COSTS", "DEFAULT_THRESHOLD", "STATUS_FAILED", "STATUS_FATAL", "assign", "imbalance"]
