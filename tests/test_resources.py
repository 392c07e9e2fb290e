"""The size limits come from the machine the code runs on (cosserat_fenicsx.resources)."""
import os
import subprocess
import sys

import pytest
from conftest import ROOT

pytestmark = pytest.mark.serial     # subprocesses, once


def _max_elements(env):
    code = "from cosserat_fenicsx import meshes; print(meshes.MAX_ELEMENTS)"
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                          env=dict(os.environ, PYTHONPATH=ROOT, **env), timeout=120)


def test_the_element_limit_follows_the_memory_a_job_is_given():
    """COSSERAT_MEMORY_BYTES = 1 GB allows 0.4 * 1e9 / 2e4 = 20,000 elements; the machine's
    memory allows more on any machine that runs the suite (well over 1 GB)."""
    small = _max_elements({"COSSERAT_MEMORY_BYTES": "1e9"})
    assert small.returncode == 0, small.stderr
    assert int(small.stdout) == 20_000
    machine = _max_elements({})
    assert int(machine.stdout) > 20_000


def test_a_malformed_memory_is_refused_in_one_line():
    for text in ("abc", "-1", "nan", "inf", "0"):
        proc = _max_elements({"COSSERAT_MEMORY_BYTES": text})
        assert proc.returncode != 0
        assert f"COSSERAT_MEMORY_BYTES={text!r}: must be a positive number of bytes" in proc.stderr
