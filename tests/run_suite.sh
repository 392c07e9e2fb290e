#!/bin/sh
# The test suite: serial pass, then the MPI pass (tests not marked serial) on NP ranks.
# Usage: tests/run_suite.sh [PYTHON] ; env NP (2), TEST_TIMEOUT (s), PYTEST_ARGS
set -e
PYTHON=${1:-/usr/bin/python3}
NP=${NP:-2}
TIMEOUT=${TEST_TIMEOUT:-1500}
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_rmaps_base_oversubscribe=1
export OMP_NUM_THREADS=1 PYTHONDONTWRITEBYTECODE=1
cd "$(dirname "$0")/.."
echo "== serial pass ($PYTHON)"
# --durations: where the time of the serial pass goes, in every log (the budget is 10 minutes)
timeout "$TIMEOUT" "$PYTHON" -m pytest -q -p no:cacheprovider --color=no --durations=15 -m "not slow" ${PYTEST_ARGS:-} tests
echo "== MPI pass: mpirun -n $NP"
timeout "$TIMEOUT" mpirun -n "$NP" "$PYTHON" -m pytest -q -p no:cacheprovider --color=no -m "not slow and not serial" ${PYTEST_ARGS:-} tests
