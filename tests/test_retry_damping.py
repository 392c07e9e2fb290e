"""The damped retry of a load step that failed with the material's operator and its fallback
(fallback.FallbackSolver(damping=), NewtonSolver.set_step_damping; docs/reference/femdem.md,
"Past the peak: ending a stagnating step").

What it must do: a damped Newton update is alpha times the full one on the free dofs while the
Dirichlet rows take their full value (a linear problem, where one full Newton update is the
solution); the retry runs once, from the committed state, on the fallback operator, and only
after both operators failed; bad dampings are refused before any work; the demo reports the
damped steps (history.csv column damped, summary.json steps_with_damped_retry) and a restart
may change the damping.
"""
import json

import numpy as np
import pytest
from mpi4py import MPI

from cosserat_fenicsx import CosseratProblem, LinearElasticMaterial, MicropolarElasticity, NewtonSolver, meshes
from cosserat_fenicsx.fallback import FallbackSolver
from cosserat_fenicsx.snes import SolveInfo
from tests.test_femdem_fallback import Problem

COMM = MPI.COMM_WORLD
ELASTIC = MicropolarElasticity(mu=1.0e8, lmbda=1.2e8, mu_c=0.4e8, l_c=0.02)


# --- the damped Newton update on a linear problem ----------------------------------------

def plate():
    """A plate pulled and sheared by its top (Dirichlet), loaded on its right side."""
    mesh, tags, names = meshes.rectangle(COMM, 0.2, 0.1, 0.025, "triangle")
    problem = CosseratProblem(mesh, tags, names, material=LinearElasticMaterial(ELASTIC))
    for component in ("u1", "u2", "phi"):
        problem.add_dirichlet("bottom", component, 0.0)
    problem.add_dirichlet("top", "u1", lambda x: 1e-4 * np.sin(10 * x[0]))
    problem.add_traction("right", (2.0e5, -1.0e5))
    problem.set_time(1.0)
    return problem


def one_update(solver, problem, damping):
    """The state after one Newton update from rest with the given damping."""
    problem.w.x.array[:] = 0.0
    solver.set_step_damping(damping)
    solver.solve()
    return problem.w.x.array.copy()


def test_a_damped_update_is_alpha_times_the_full_one_on_the_free_dofs():
    problem = plate()
    solver = NewtonSolver(problem, options={"snes_linesearch_type": "basic", "snes_max_it": 1})
    full = one_update(solver, problem, None)
    damped = one_update(solver, problem, 0.3)
    n_owned = solver.x.getLocalSize()
    bc = np.zeros(len(full), dtype=bool)
    bc[solver._owned_dirichlet_rows()] = True
    owned = np.arange(len(full)) < n_owned
    assert np.any(full[owned & ~bc] != 0)
    # free dofs: 0.3 of the full update; Dirichlet rows: their value, as without damping
    assert np.allclose(damped[owned & ~bc], 0.3 * full[owned & ~bc], rtol=1e-10, atol=1e-20)
    assert np.array_equal(damped[owned & bc], full[owned & bc])
    # back to full steps: the same update as before, bit for bit
    assert np.array_equal(one_update(solver, problem, None), full)
    assert np.array_equal(one_update(solver, problem, 1.0), full)
    solver.destroy()


def test_the_kept_operator_rule_is_scaled_to_the_damped_step():
    """An iteration that contracts by c undamped contracts by 1 - alpha (1 - c) damped: the
    kept operator is rebuilt only below that."""
    problem = plate()
    solver = NewtonSolver(problem, force_rtol=1e-2, jacobian_refresh=0.7)
    assert solver._refresh_factor() == 0.7
    solver.set_step_damping(0.3)
    assert solver._refresh_factor() == pytest.approx(0.91)
    solver.set_step_damping(None)
    assert solver._refresh_factor() == 0.7
    for bad in (0, -0.1, 1.5, float("nan"), True, "0.3"):
        with pytest.raises(ValueError, match="step damping"):
            solver.set_step_damping(bad)
    solver.destroy()


# --- the retry logic, on stand-ins (as tests/test_femdem_fallback.py) -----------------------

class Material:
    def __init__(self, has_fallback=True):
        self.has_fallback, self.on = has_fallback, False

    def use_fallback_operator(self, on):
        changed = self.has_fallback and bool(on) != self.on
        self.on = bool(on) and self.has_fallback
        return changed


class Newton:
    """Solves converge as listed per kind of solve: 'own', 'fallback', 'damped'."""

    def __init__(self, material, **outcomes):
        self.material, self.outcomes, self.solves = material, {k: list(v) for k, v in outcomes.items()}, []
        self.damping = None

    def set_step_damping(self, alpha):
        self.damping = alpha

    def solve(self):
        kind = ("damped" if self.damping else "fallback") if self.material.on else "own"
        assert kind != "damped" or self.material.on        # the damped retry runs on the fallback only
        self.solves.append(kind)
        ok = self.outcomes[kind].pop(0)
        return SolveInfo(converged=ok, iterations=7 if ok else 25, residual=0.0, reason="R",
                         failure="" if ok else "stagnated at FNORM/RNORM 0.059")


def test_a_step_failed_with_both_operators_is_solved_once_more_damped():
    material, problem = Material(), Problem()
    newton = Newton(material, own=[False, True], fallback=[False, True, False], damped=[True, True])
    solver = FallbackSolver(newton, problem, material, hold=1, damping=0.3)
    info = solver.solve()
    assert newton.solves == ["own", "fallback", "damped"]
    assert info.converged and info.damped and "0.059" in info.fallback
    assert info.iterations == 25 + 25 + 7 and problem.rollbacks == 2
    assert newton.damping is None and not material.on       # both restored after the retry
    assert solver.held == 1 and solver.damped_steps == 1
    # the held step after it (on the fallback), then the own operator again
    assert solver.solve().converged and solver.solve().converged
    assert newton.solves[3:] == ["fallback", "own"]
    # a held step that fails is retried damped as well
    solver.held = 1
    info = solver.solve()
    assert newton.solves[5:] == ["fallback", "damped"] and info.damped and info.converged
    assert "held" in info.fallback and solver.damped_steps == 2


def test_a_damped_retry_that_fails_goes_to_the_stepping():
    material, problem = Material(), Problem()
    newton = Newton(material, own=[False], fallback=[False], damped=[False])
    solver = FallbackSolver(newton, problem, material, damping=0.3)
    info = solver.solve()
    assert not info.converged and not info.damped and solver.held == 0 and solver.damped_steps == 0
    assert newton.solves == ["own", "fallback", "damped"] and newton.damping is None and not material.on


@pytest.mark.parametrize("has_fallback, damping", [(True, None), (False, 0.3)])
def test_no_damped_retry_without_damping_or_without_a_fallback(has_fallback, damping):
    material, problem = Material(has_fallback), Problem()
    newton = Newton(material, own=[False], fallback=[False], damped=[True])
    info = FallbackSolver(newton, problem, material, damping=damping).solve()
    assert not info.converged and "damped" not in newton.solves


def test_the_scene_does_not_retry_damped_by_default():
    from cosserat_fenicsx.scenes.femdem_biaxial import FemDemSettings
    assert FemDemSettings().retry_damping == 0.0


@pytest.mark.parametrize("bad", [0, -0.3, 1.2, True, "0.3"])
def test_the_damping_is_checked(bad):
    with pytest.raises(ValueError, match="damping"):
        FallbackSolver(None, None, None, damping=bad)


# --- the demo ------------------------------------------------------------------------------

SMALL = ("--mesh", "1x1", "--particles", 20, "--axial-strain", 0.002, "--steps", 2)


@pytest.mark.serial
@pytest.mark.parametrize("bad", ["-0.1", "1.5", "nan", "half"])
def test_a_bad_damping_is_refused_in_one_line_before_any_work(demo, tmp_path, bad):
    proc = demo("femdem_biaxial", *SMALL, "--retry-damping", bad, "--out", tmp_path / "bad", check=False)
    assert proc.returncode == 2
    lines = [line for line in proc.stderr.splitlines() if "--retry-damping" in line]
    assert len(lines) == 1 and "Traceback" not in proc.stderr
    assert not (tmp_path / "bad").exists() or not (tmp_path / "bad" / "history.csv").exists()


@pytest.mark.serial
def test_the_demo_reports_damped_steps_and_a_restart_may_change_the_damping(demo, tmp_path):
    part = tmp_path / "part"
    demo("femdem_biaxial", *SMALL, "--out", part, "--stop-after", 1)
    proc = demo("femdem_biaxial", "--restart", part, "--retry-damping", "0.3")
    assert "--retry-damping 0.0 -> 0.3" in proc.stdout
    summary = json.loads((part / "summary.json").read_text())
    assert summary["completed"] and summary["steps_with_damped_retry"] == 0
    assert summary["changed_at_restart"] == {"retry_damping": [0.0, 0.3]}
    header = (part / "history.csv").read_text().splitlines()[0].split(",")
    assert "damped" in header and header.index("damped") == header.index("fallback") + 1


@pytest.mark.serial
def test_in_the_scene_a_step_failed_with_both_operators_is_retried_damped_then_cut():
    """A force_rtol no cell can reach: every solve fails, so each try of the first step is the
    material's operator, the fallback and the damped retry (3 iterations each), then the cut;
    the scene goes back to its own operator and full updates after each."""
    from cosserat_fenicsx.scenes.femdem_biaxial import FemDemBiaxial, FemDemSettings
    from cosserat_fenicsx.materials.dem import CellOptions
    from cosserat_fenicsx.stepping import LoadSteppingError

    settings = FemDemSettings(nx=1, ny=1, mode="classical", axial_strain=0.002, steps=2, force_rtol=1e-14, retry_damping=0.3,
                              accept_rtol=1e-14, dt_min_fraction=0.5, solver_options={"snes_max_it": 3},
                              cell=CellOptions(particles=20, seed=1))
    test = FemDemBiaxial(COMM, settings, verbose=False)
    with pytest.raises(LoadSteppingError, match="after 9 iterations"):
        test.run()
    infos = test.solver.infos
    assert len(infos) == 2 and not any(i.converged or i.damped for i in infos)
    assert test.fallback.failures == 2 and test.fallback.damped_steps == 0
    assert test.newton.step_damping is None and test.material.tangent_kind.name == "pstlo"
