"""Numba's CUDA simulator (NUMBA_ENABLE_CUDASIM=1), made fit to run these kernels in tests.

The simulator runs every thread of a block as a Python thread. Three of its habits get in the
way of kernels that call device functions from several modules with many barriers:

1. On entry to a device function it swaps the `cuda` global of the function's module for its
   fake module, and back on exit, thread by thread: with two threads inside functions of one
   module, the first to leave restores the real module under the other (AttributeError:
   module 'numba.cuda' has no attribute 'threadIdx'). ``patch`` makes the swap count the
   threads inside each module and restore on the last exit; the fake module answers each
   thread with its own indices, so one swap serves them all.
2. Its shared arrays are looked up by the calling line and created by the first thread to
   ask, with no lock: two threads that ask at once can each create their own, and a block
   then runs with a private `shared` array in one thread (seen as garbage indices, rarely).
   ``patch`` makes the look-up and the creation one step under a lock.
3. Its scheduler polls the threads in a busy loop that holds the interpreter lock for the
   switch interval (5 ms) at a time, so each barrier costs milliseconds. ``fast_barriers``
   lowers the switch interval while a kernel runs (6x faster here).

None changes what a kernel computes. Nothing here runs unless the simulator is on.
"""
import sys
import threading
from contextlib import contextmanager

_lock = threading.Lock()
_inside = {}          # id(module globals) -> [threads inside, the globals swapped out]
_patched = False
_shared_lock = threading.Lock()


@contextmanager
def _swapped_cuda_module(fn, fake_cuda_module):
    from numba import cuda
    glob = fn.__globals__
    key = id(glob)
    with _lock:
        entry = _inside.get(key)
        if entry is None:
            orig = {name: value for name, value in glob.items() if value is cuda}
            glob.update({name: fake_cuda_module for name in orig})
            entry = _inside[key] = [0, orig]
        entry[0] += 1
    try:
        yield
    finally:
        with _lock:
            entry[0] -= 1
            if entry[0] == 0:
                glob.update(entry[1])
                del _inside[key]


def _shared_array(original):
    """FakeCUDAShared.array with its look-up-or-create under a lock; keyed, as the
    simulator keys it, by the calling file and line."""
    def array(self, shape, dtype):
        if shape == 0:
            return original(self, shape, dtype)
        caller = sys._getframe(1)
        key = (caller.f_code.co_filename, caller.f_lineno)
        with _shared_lock:
            res = self._allocations.get(key)
            if res is None:
                res = _empty(shape, dtype)
                self._allocations[key] = res
        return res
    return array


def _empty(shape, dtype):
    import numpy as np
    from numba.core import types
    from numba.np import numpy_support
    if isinstance(dtype, types.Type):
        dtype = numpy_support.as_dtype(dtype)
    return np.empty(shape, dtype)


def patch():
    """Install the counted swap and the locked shared arrays in the simulator (once; only
    with NUMBA_ENABLE_CUDASIM=1)."""
    global _patched
    from numba import config
    if _patched or not config.ENABLE_CUDASIM:
        return
    from numba.cuda.simulator import kernel, kernelapi
    kernel.swapped_cuda_module = _swapped_cuda_module
    kernelapi.FakeCUDAShared.array = _shared_array(kernelapi.FakeCUDAShared.array)
    _patched = True


@contextmanager
def fast_barriers(interval=1e-4):
    """A short switch interval for the simulator's threads while the block runs (no-op on a
    GPU)."""
    from numba import config
    if not config.ENABLE_CUDASIM:
        yield
        return
    old = sys.getswitchinterval()
    sys.setswitchinterval(interval)
    try:
        yield
    finally:
        sys.setswitchinterval(old)
