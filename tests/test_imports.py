"""Leave out what a scene does not need: an elastic scene compiles no Numba kernel,
builds no quadrature callback and imports no demcell; a Cauchy scene has no rotation."""
import json
import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
pytestmark = pytest.mark.serial

ELASTIC_SCENE = """
import sys, json
sys.path.insert(0, {root!r})
from mpi4py import MPI
from cosserat_fenicsx import CosseratProblem, MicropolarElasticity, NewtonSolver, LoadStepper, meshes
mesh, tags, names = meshes.rectangle(MPI.COMM_WORLD, 1.0, 1.0, 0.25)
p = CosseratProblem(mesh, tags, names, elasticity=MicropolarElasticity(1e8, 1e8, l_c=0.1))
p.add_dirichlet("bottom", "u1", 0.0); p.add_dirichlet("bottom", "u2", 0.0); p.add_dirichlet("bottom", "phi", 0.0)
p.add_traction("top", (1e5, 0.0))
LoadStepper(p, NewtonSolver(p), verbose=False).run()
print(json.dumps({{name: name in sys.modules for name in
      ("numba", "demcell", "cosserat_fenicsx.materials", "cosserat_fenicsx.quadrature")}}))
"""


def modules_after(code):
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_elastic_scene_imports_no_numba_no_callback_no_demcell():
    loaded = modules_after(ELASTIC_SCENE.format(root=ROOT))
    assert not loaded["demcell"]
    assert not loaded["cosserat_fenicsx.materials"]
    assert not loaded["cosserat_fenicsx.quadrature"]
    # dolfinx 0.9 imports numba itself; then our code must add nothing to that
    dolfinx_numba = modules_after("import sys, json, dolfinx; print(json.dumps({'numba': 'numba' in sys.modules}))")
    assert loaded["numba"] == dolfinx_numba["numba"]


def test_material_package_does_not_import_dolfinx():
    loaded = modules_after(f"import sys, json; sys.path.insert(0, {ROOT!r}); "
                           "import cosserat_fenicsx.materials; "
                           "print(json.dumps({'dolfinx': 'dolfinx' in sys.modules, 'numba': 'numba' in sys.modules}))")
    assert loaded == {"dolfinx": False, "numba": False}


def test_cauchy_scene_has_no_rotation_field():
    from mpi4py import MPI
    from cosserat_fenicsx import CosseratProblem, MicropolarElasticity, meshes
    mesh, tags, names = meshes.rectangle(MPI.COMM_WORLD, 1.0, 1.0, 0.5)
    p = CosseratProblem(mesh, tags, names, elasticity=MicropolarElasticity(1e8, 1e8), micropolar=False)
    assert p.W.num_sub_spaces == 2 and p.W.sub(0).num_sub_spaces == 0   # u1, u2 only
    assert p.rotation is None and p.couple_stress() is None
    with pytest.raises(ValueError, match="no rotation field"):
        p.add_dirichlet("left", "phi", 0.0)


DEM_SCENE = """
import sys, json
sys.path.insert(0, {root!r})
from mpi4py import MPI
from cosserat_fenicsx.materials.dem import CellOptions
from cosserat_fenicsx.scenes.femdem_biaxial import FemDemBiaxial, FemDemSettings
test = FemDemBiaxial(MPI.COMM_WORLD, FemDemSettings(nx=1, ny=1, steps=1, axial_strain=1e-3,
                                                   cell=CellOptions(particles=30)), verbose=False)
test.run()
print(json.dumps({{name: name in sys.modules for name in
      ("demcell", "cosserat_fenicsx.materials.ehlers", "cosserat_fenicsx.materials.ehlers.local_solver")}}))
"""

EHLERS_SCENE = """
import sys, json
sys.path.insert(0, {root!r})
from mpi4py import MPI
from cosserat_fenicsx.scenes.biaxial import BiaxialSettings, BiaxialTest
test = BiaxialTest(MPI.COMM_WORLD, BiaxialSettings(cell_size=0.025, steps=1, consolidation_steps=1,
                                                   axial_strain=1e-3), verbose=False)
test.run()
print(json.dumps({{name: name in sys.modules for name in
      ("demcell", "cosserat_fenicsx.materials.dem", "cosserat_fenicsx.materials.ehlers")}}))
"""


def test_dem_scene_imports_no_ehlers_kernel():
    loaded = modules_after(DEM_SCENE.format(root=ROOT))
    assert loaded == {"demcell": True, "cosserat_fenicsx.materials.ehlers": False,
                      "cosserat_fenicsx.materials.ehlers.local_solver": False}


def test_ehlers_scene_imports_no_demcell():
    loaded = modules_after(EHLERS_SCENE.format(root=ROOT))
    assert loaded == {"demcell": False, "cosserat_fenicsx.materials.dem": False,
                      "cosserat_fenicsx.materials.ehlers": True}


def test_cpu_cells_load_no_cuda():
    """The CUDA target loads only when a GPU batch is asked for (demcell.gpu)."""
    loaded = modules_after(f"import sys, json; sys.path.insert(0, {ROOT!r}); import numpy as np, demcell; "
                           "from demcell.batch import CellBatch; "
                           "print(json.dumps({'cuda': 'numba.cuda' in sys.modules, 'gpu': 'demcell.gpu' in sys.modules}))")
    assert loaded == {"cuda": False, "gpu": False}
