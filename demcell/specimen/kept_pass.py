"""A contact pass evaluated ahead of the step that would repeat it (Specimen.forces_now(keep=True)).

The bridging-scale coupler needs the grain forces at the end of its DEM sub-steps (003 eq 33),
which are the forces the next sub-step starts from. ``KeptPass`` holds that pass (the contact
history as the step would update it, the pair forces, the wall and plate loads) in buffers of
its own, with a snapshot of everything the pass depends on; the next step uses it only if the
engine is still as the pass saw it. The buffers live as long as the neighbour list (a
rebuild changes the pair arrays' length and they are allocated again), so a coarse step costs
copies into existing arrays and compiled comparisons, not allocations and Python loops.
"""
import numpy as np
from numba import njit


@njit(cache=True)
def same_values(a, b):
    """True if the C-contiguous arrays a and b hold the same values (NaN differs from itself,
    as in np.array_equal); shapes are compared by the caller."""
    x = a.ravel()
    y = b.ravel()
    for i in range(x.size):
        if x[i] != y[i]:
            return False
    return True


def _copies_into(buffers, sources):
    """The sources copied into `buffers` where every shape and dtype still fits, else fresh
    copies (a list)."""
    if buffers is not None and all(b.shape == s.shape and b.dtype == s.dtype for b, s in zip(buffers, sources)):
        for b, s in zip(buffers, sources):
            np.copyto(b, s)
        return buffers
    return [np.array(s, copy=True) for s in sources]


class KeptPass:
    """One kept contact pass of a Specimen.

    state_names, engine_names: the arrays of the SpecimenState and of the Specimen that the pass
    modifies (copied in before it, copied back when the step takes it); scratch_names: the
    Specimen's per-pair scratch arrays the pass fills completely (swapped, not copied);
    state_inputs, engine_inputs: the arrays of the SpecimenState and of the Specimen whose
    values the pass read (compared when the step takes it)."""

    def __init__(self, state_names, engine_names, scratch_names, state_inputs, engine_inputs):
        self.state_names = tuple(state_names)
        self.engine_names = tuple(engine_names)
        self.scratch_names = tuple(scratch_names)
        self.state_inputs = tuple(state_inputs)
        self.engine_inputs = tuple(engine_inputs)
        self._buffers = None
        self._scratch = None
        self._snapshot = None
        self._scalars = None
        self.pending = False

    def _modified(self, specimen):
        st = specimen.state
        return [getattr(st, n) for n in self.state_names] + [getattr(specimen, n) for n in self.engine_names]

    def _inputs(self, specimen):
        st = specimen.state
        return [getattr(st, n) for n in self.state_inputs] + [getattr(specimen, n) for n in self.engine_inputs]

    def prepare(self, specimen):
        """{name: buffer} holding copies of the arrays the pass modifies and of the scratch
        arrays (to be filled by the pass); drops any pending pass."""
        self.pending = False
        self._buffers = _copies_into(self._buffers, self._modified(specimen))
        scratch = [getattr(specimen, n) for n in self.scratch_names]
        if self._scratch is None or any(a.shape != b.shape for a, b in zip(self._scratch, scratch)):
            self._scratch = [np.empty_like(a) for a in scratch]
        names = self.state_names + self.engine_names + self.scratch_names
        return dict(zip(names, self._buffers + self._scratch))

    def keep(self, specimen, scalars):
        """Mark the prepared pass as the next step's, with the scalars it depends on and a
        snapshot of its input arrays."""
        self._snapshot = _copies_into(self._snapshot, self._inputs(specimen))
        self._scalars = scalars
        self.pending = True

    def take(self, specimen, scalars):
        """True after copying the pending pass into the specimen, if the scalars and the
        input arrays are as when it was kept; the pass is dropped either way."""
        if not self.pending:
            return False
        self.pending = False
        if scalars != self._scalars:
            return False
        for now, saved in zip(self._inputs(specimen), self._snapshot):
            if now.shape != saved.shape or now.dtype != saved.dtype or not same_values(np.ascontiguousarray(now), saved):
                return False
        if any(getattr(specimen, n).shape != b.shape for n, b in zip(self.scratch_names, self._scratch)):
            return False
        for target, kept in zip(self._modified(specimen), self._buffers):
            np.copyto(target, kept)
        # the scratch arrays are filled completely by every pass: swapped, not copied
        for k, name in enumerate(self.scratch_names):
            mine = self._scratch[k]
            self._scratch[k] = getattr(specimen, name)
            setattr(specimen, name, mine)
        return True

    def drop(self):
        self.pending = False

    def load_kernels(self, specimen):
        """The comparison compiled (loaded from Numba's cache) for every input array's type
        now, in the specimen's set-up."""
        for a in self._inputs(specimen):
            same_values(np.ascontiguousarray(a), np.ascontiguousarray(a))
