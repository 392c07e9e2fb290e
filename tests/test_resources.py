"""The size limits come from the machine the code runs on (cosserat_fenicsx.resources)."""
import pytest

pytestmark = pytest.mark.serial     # subprocesses, once


def test_the_element_limit_follows_the_memory_a_job_is_given(monkeypatch):
    """COSSERAT_MEMORY_BYTES = 1 GB allows 0.4 * 1e9 / 2e4 = 20,000 elements; the machine's
    memory allows more on any machine that runs the suite (well over 1 GB)."""
    from cosserat_fenicsx import meshes
    monkeypatch.setenv("COSSERAT_MEMORY_BYTES", "1e9")
    assert meshes.max_elements() == 20_000
    assert meshes.rectangle_divisions(1.0, 1.0, 1.0 / 100.0) == (100, 100)     # 2 x 100 x 100: at the limit
    with pytest.raises(meshes.InputError, match=r"gives 2.04e\+04 triangles .* at most 2e\+04"):
        meshes.rectangle_divisions(1.0, 1.0, 1.0 / 101.0)                     # 2 x 101 x 101
    monkeypatch.delenv("COSSERAT_MEMORY_BYTES")
    assert meshes.max_elements() > 20_000


@pytest.mark.parametrize("text", ["abc", "-1", "nan", "inf", "0"])
def test_a_malformed_memory_is_refused_in_one_line_by_a_demo(demo, tmp_path, monkeypatch, text):
    monkeypatch.setenv("COSSERAT_MEMORY_BYTES", text)
    proc = demo("shear_layer", "--out", tmp_path / "out", check=False, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip() == f"shear_layer.py: error: COSSERAT_MEMORY_BYTES={text!r}: must be a positive number of bytes"
