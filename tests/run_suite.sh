#!/bin/sh
# The test suite: serial pass, then the MPI pass (tests not marked serial) on NP ranks.
# Usage: tests/run_suite.sh [PYTHON] ; env NP (2), JOBS (2), TEST_TIMEOUT (s), PYTEST_ARGS
set -e
PYTHON=${1:-/usr/bin/python3}
NP=${NP:-2}
TIMEOUT=${TEST_TIMEOUT:-1500}
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_rmaps_base_oversubscribe=1
export OMP_NUM_THREADS=1 PYTHONDONTWRITEBYTECODE=1
cd "$(dirname "$0")/.."
# The serial pass on JOBS pytest workers (pytest-xdist, python3-pytest-xdist; a test file stays
# on one worker, so module fixtures are built once): 2 by default, the number of cores of the
# machines the budget of 10 minutes is meant for. Without xdist, or with JOBS=1, one process.
JOBS=${JOBS:-2}
WORKERS=""
if [ "$JOBS" -gt 1 ] && "$PYTHON" -c "import xdist" 2>/dev/null; then
    WORKERS="-n $JOBS --dist loadfile"
fi
echo "== serial pass ($PYTHON${WORKERS:+, $WORKERS})"
# --durations: where the time of the serial pass goes, in every log
timeout "$TIMEOUT" "$PYTHON" -m pytest -q -p no:cacheprovider --color=no --durations=15 $WORKERS -m "not slow" ${PYTEST_ARGS:-} tests
echo "== MPI pass: mpirun -n $NP"
timeout "$TIMEOUT" mpirun -n "$NP" "$PYTHON" -m pytest -q -p no:cacheprovider --color=no -m "not slow and not serial" ${PYTEST_ARGS:-} tests
