"""Bad input gets a clear error before any assembly (API and command line)."""
import pytest
from mpi4py import MPI

from cosserat_fenicsx import CosseratProblem, MicropolarElasticity, NewtonSolver, meshes


@pytest.mark.parametrize("kwargs, message", [
    (dict(mu=-1.0, lmbda=1.0), "shear modulus mu must be positive"),
    (dict(mu=1.0, lmbda=-1.0), "bulk modulus"),
    (dict(mu=1.0, lmbda=1.0, mu_c=-1.0), "mu_c must be >= 0"),
    (dict(mu=1.0, lmbda=1.0, l_c=-0.1), "l_c must be >= 0"),
    (dict(mu=float("nan"), lmbda=1.0), "finite number"),
])
def test_bad_moduli(kwargs, message):
    with pytest.raises(ValueError, match=message):
        MicropolarElasticity(**kwargs)


@pytest.fixture(scope="module")
def square():
    return meshes.rectangle(MPI.COMM_WORLD, 1.0, 1.0, 0.5)


def test_zero_coupling_in_a_micropolar_scene(square):
    with pytest.raises(ValueError, match="mu_c = 0 .* undetermined"):
        CosseratProblem(*square, elasticity=MicropolarElasticity(1.0, 1.0, mu_c=0.0, l_c=0.1))


def test_unknown_boundary_and_component(square):
    p = CosseratProblem(*square, elasticity=MicropolarElasticity(1.0, 1.0, l_c=0.1))
    with pytest.raises(ValueError, match="unknown boundary 'botom'"):
        p.add_dirichlet("botom", "u1", 0.0)
    with pytest.raises(ValueError, match="unknown component 'u3'"):
        p.add_dirichlet("bottom", "u3", 0.0)
    with pytest.raises(ValueError, match="boundary tags not found"):
        CosseratProblem(*square[:2], {"hole": 99}, elasticity=MicropolarElasticity(1.0, 1.0, l_c=0.1))


def test_inconsistent_boundary_conditions(square):
    p = CosseratProblem(*square, elasticity=MicropolarElasticity(1.0, 1.0, l_c=0.1))
    p.add_dirichlet("top", "u2", 0.0)
    with pytest.raises(ValueError, match="inconsistent boundary conditions: u2 on 'top'"):
        p.add_traction("top", (0.0, 1.0))
    p.add_surface_couple("left", 1.0)
    with pytest.raises(ValueError, match="inconsistent boundary conditions: phi on 'left'"):
        p.add_dirichlet("left", "phi", 0.0)
    with pytest.raises(ValueError, match="two Dirichlet conditions"):
        p.add_dirichlet("top", "u2", 1.0)


def test_no_dirichlet_condition_before_assembly(square):
    p = CosseratProblem(*square, elasticity=MicropolarElasticity(1.0, 1.0, l_c=0.1))
    p.add_traction("top", (0.0, 1.0))
    with pytest.raises(ValueError, match="rigid-body motion is undetermined"):
        NewtonSolver(p)


def test_missing_mesh_file():
    with pytest.raises(FileNotFoundError, match="gmsh source not found"):
        meshes.from_gmsh_geo(MPI.COMM_WORLD, "/nonexistent/plate.geo", {})


def test_both_or_neither_material(square):
    with pytest.raises(ValueError, match="exactly one"):
        CosseratProblem(*square)


@pytest.mark.serial
@pytest.mark.parametrize("demo_name, args, message", [
    ("shear_layer", ["--mu", "-5"], "argument --mu: must be > 0, got -5"),
    ("shear_layer", ["--cell-size", "0"], "argument --cell-size: must be > 0, got 0"),
    ("shear_layer", ["--mu-c", "0"], "mu_c = 0"),
    ("shear_layer", ["--no-such-option"], "unrecognized argument"),
    ("shear_layer", ["--height", "-1"], "argument --height: must be > 0, got -1"),
    ("shear_layer", ["--lmbda", "-1e9"], "bulk modulus"),
    ("hole_plate", ["--radius", "0.1", "--half-side", "0.05"], "half_side must be > radius (0.1 m), got 0.05 m"),
    ("hole_plate", ["--traction", "0"], "--traction must have a magnitude in [1e-6, 1e12] Pa, got 0"),
    ("hole_plate", ["--traction", "nan"], "argument --traction: must be a finite number, got nan"),
    ("hole_plate", ["--l-c", "0", "--sweep"], "--sweep varies a/l_c: it needs --l-c > 0"),
    ("biaxial", ["--weak-size", "0.2"], "weak_size must be in [0, 0.05), got 0.2"),
    ("biaxial", ["--k-sigma", "-1"], "argument --k-sigma: must be >= 0, got -1"),
    ("biaxial", ["--cell-size", "1e-4"], "gives 1e+06 triangles in a 0.05 x 0.1 m rectangle; at most 5e+05"),
    ("femdem_biaxial", ["--mesh", "1000x1000"], "needs about 684 GB for its cells; at most 15.5 GB (0.6 of the 25.8 GB of memory)"),
    ("femdem_biaxial", ["--max-dem-steps", "1e300"], "argument --max-dem-steps: must be an integer in [1, 1e+09]"),
    ("dem_cell", ["--increment", "1e-300"], "at most a million increments"),
    ("material_point", ["--dt", "nan"], "argument --dt: must be > 0, got nan"),
    ("biaxial", ["--classical", "--mu-c", "0", "--eta", "inf"], "argument --eta: must be >= 0, got inf"),
])
def test_demo_rejects_bad_options_before_work(demo, tmp_path, monkeypatch, demo_name, args, message):
    # the size limits follow the memory (resources.memory_bytes): the messages are those of 24 GiB
    monkeypatch.setenv("COSSERAT_MEMORY_BYTES", str(24 * 2**30))
    proc = demo(demo_name, *args, "--out", tmp_path / "out", check=False, timeout=60)
    assert proc.returncode == 2
    assert message in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr     # one line, no usage block
    assert not (tmp_path / "out").exists()                              # no output directory left behind


@pytest.mark.parametrize("method, args, message", [
    ("add_traction", ("top", (0.0, float("nan"))), "traction on 'top' must be a finite number, got nan"),
    ("add_traction", ("top", (float("inf"), 0.0)), "traction on 'top' must be a finite number"),
    ("add_surface_couple", ("top", float("nan")), "surface couple on 'top' must be a finite number"),
    ("set_body_force", ((0.0, float("-inf")),), "body force must be a finite number"),
    ("add_dirichlet", ("top", "u1", float("nan")), "not finite"),
    ("add_point_dirichlet", ((0.5, float("nan")), "u1", 0.0), "point of the u1 pin must be a finite number"),
])
def test_non_finite_loads_are_refused_before_the_form_compiler(square, method, args, message):
    p = CosseratProblem(*square, elasticity=MicropolarElasticity(1.0, 1.0, l_c=0.1))
    with pytest.raises(ValueError, match=message):
        getattr(p, method)(*args)


def test_mesh_too_fine_is_refused_before_meshing():
    with pytest.raises(ValueError, match="triangles in a 1 x 1 m rectangle; at most 5e\\+05"):
        meshes.rectangle(MPI.COMM_WORLD, 1.0, 1.0, 1e-300)
    with pytest.raises(ValueError, match="radius / half_side must be in"):
        meshes.hole_plate(MPI.COMM_WORLD, 1e-9, 1.0, 0.1)


def test_overflowing_bending_modulus_is_refused():
    with pytest.raises(ValueError, match="bending modulus 2 mu_c l_c\\^2 overflows"):
        MicropolarElasticity(1e8, 1e8, l_c=1e300)
