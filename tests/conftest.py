import json
import logging
import os
import subprocess
import sys

# demcell.gpu's kernels run in Numba's CUDA simulator under `make test` (no GPU needed; set
# before anything imports numba, which reads it once)
os.environ.setdefault("NUMBA_ENABLE_CUDASIM", "1")

import pytest  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
logging.getLogger().setLevel(logging.WARNING)


def run_demo(name, *args, ranks=None, check=True, timeout=600):
    """Run demos/<name>.py as a user would (optionally under mpirun); returns the
    CompletedProcess. Used by serial tests only (never mpirun inside mpirun)."""
    cmd = [sys.executable, os.path.join(ROOT, "demos", name + ".py"), *map(str, args)]
    if ranks:
        cmd = ["mpirun", "-n", str(ranks)] + cmd
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1", OMP_NUM_THREADS="1")
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env, cwd=ROOT)
    if check and proc.returncode != 0:
        raise AssertionError(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    return proc


def read_summary(out):
    with open(os.path.join(out, "summary.json")) as f:
        return json.load(f)


@pytest.fixture
def demo():
    return run_demo
