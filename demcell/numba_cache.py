"""Drop demcell's Numba cache when any of its sources changed.

``cache=True`` keys a compiled kernel on the file that defines it and nothing else: a kernel
that calls into another module (``quasistatic``'s batched solve calls ``relaxation.advance``,
``batch`` calls ``homogenization`` and ``tangent``) keeps the callee it was compiled with
after that module changes (Numba issue #6845). After a ``git pull`` or an edit the batched
cells would then run the old force loop, silently. The package therefore stamps its sources
(one SHA-1 over all ``*.py`` of the package and its subpackages, about 1 ms) and deletes
their cached kernels (``__pycache__/*.nbi``, ``*.nbc``, CPU and CUDA alike) when the stamp
differs; Numba recompiles them on first use.

Two processes importing at once (``mpirun``) may both clear: the loser only recompiles. A
read-only install cannot write the stamp; Numba then caches elsewhere (NUMBA_CACHE_DIR or
the user's cache) and this guard does not reach that cache.
"""
import glob
import hashlib
import os

STAMP = "numba_sources.sha1"


def sources_digest(package_dir):
    """SHA-1 of the package's Python sources (its subpackages' too: the GPU kernels of
    demcell.gpu take their slot numbers from the package), in path order."""
    digest = hashlib.sha1()
    for path in sorted(glob.glob(os.path.join(package_dir, "**", "*.py"), recursive=True)):
        digest.update(os.path.relpath(path, package_dir).encode())
        with open(path, "rb") as f:
            digest.update(f.read())
    return digest.hexdigest()


def clear_stale_cache(package_dir):
    """Delete the cached kernels of ``package_dir`` if its sources changed since the last
    stamp; returns True if it cleared them."""
    cache = os.path.join(package_dir, "__pycache__")
    stamp = os.path.join(cache, STAMP)
    digest = sources_digest(package_dir)
    try:
        with open(stamp) as f:
            if f.read().strip() == digest:
                return False
    except OSError:
        pass
    caches = glob.glob(os.path.join(package_dir, "**", "__pycache__"), recursive=True)
    for path in [p for c in caches for p in glob.glob(os.path.join(c, "*.nbi")) + glob.glob(os.path.join(c, "*.nbc"))]:
        try:
            os.remove(path)
        except OSError:
            pass
    try:
        os.makedirs(cache, exist_ok=True)
        tmp = f"{stamp}.{os.getpid()}"
        with open(tmp, "w") as f:
            f.write(digest + "\n")
        os.replace(tmp, stamp)
    except OSError:
        pass
    return True
