"""demcell's cells on a GPU: ``DeviceCellBatch``, a batch of cells resident on a CUDA device
with the methods of ``demcell.batch.CellBatch`` (Numba's CUDA target).

    from demcell.gpu import available, DeviceCellBatch
    reason = available()            # None, or why no GPU can be used here
    batch = DeviceCellBatch(cells)  # as CellBatch(cells)

Nothing here is imported by ``import demcell``: the CUDA target loads only when a GPU batch is
asked for. ``NUMBA_ENABLE_CUDASIM=1`` runs the same kernels in Numba's CUDA simulator on the
CPU (slowly): the tests compare them there with CellBatch bit for bit. docs/results/gpu.md says how
to run on a GPU and what it gives.
"""


def available():
    """None if a CUDA device (or Numba's simulator) can run the cells here, else the reason
    in one line."""
    try:
        from numba import cuda
    except ImportError as error:       # a Numba without its CUDA target
        return f"Numba's CUDA target cannot be imported ({error}); install numba-cuda"
    try:
        if cuda.is_available():
            return None
    except Exception as error:         # a driver that fails to load
        return f"no usable CUDA device ({type(error).__name__}: {error})"
    return ("no CUDA device (numba.cuda.is_available() is False: no NVIDIA GPU or driver; "
            "NUMBA_ENABLE_CUDASIM=1 runs the simulator, for tests)")


def DeviceCellBatch(cells, threads=None):
    """batch.DeviceCellBatch (imported on first use: it loads Numba's CUDA target). threads
    per cell: default 128 on a GPU, 4 in the simulator (which runs each as a Python thread)."""
    from numba import config

    from .batch import DEFAULT_THREADS
    from .batch import DeviceCellBatch as _Batch
    if threads is None:
        threads = SIMULATOR_THREADS if config.ENABLE_CUDASIM else DEFAULT_THREADS
    return _Batch(cells, threads)


#: threads per cell in Numba's CUDA simulator
SIMULATOR_THREADS = 4


def use_device(rank=0):
    """Make CUDA device rank % (devices) the current one (MPI ranks each on their own GPU, or
    sharing them in turn); returns the device in words."""
    from numba import config, cuda
    if not config.ENABLE_CUDASIM:
        cuda.select_device(int(rank) % len(cuda.gpus))
    from .batch import device_summary
    return device_summary()
