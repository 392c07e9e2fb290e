"""What the machine the code runs on can hold: the memory that sizes the refusals of
problems too large to solve (meshes.max_elements, the FEM x DEM cells' memory).

The memory is the machine's physical memory, or the environment variable
COSSERAT_MEMORY_BYTES where a job has less than the machine (a batch scheduler's
allocation) or a user wants a lower ceiling.
"""
import math
import os

from .validation import InputError

MEMORY_VARIABLE = "COSSERAT_MEMORY_BYTES"


def memory_bytes():
    """Bytes of memory a run may plan for: COSSERAT_MEMORY_BYTES if set (a positive number),
    else the machine's physical memory. InputError in one line for a malformed value."""
    text = os.environ.get(MEMORY_VARIABLE)
    if text is not None:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not (math.isfinite(value) and value > 0):
            raise InputError(f"{MEMORY_VARIABLE}={text!r}: must be a positive number of bytes")
        return value
    return float(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
