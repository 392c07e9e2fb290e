# Two commands on a fresh Debian 12 (or 13) machine:
#   make demo   installs the missing Debian packages, runs the default demo on 2 ranks
#   make test   the test suite, serial then under mpirun -n 2
PYTHON ?= /usr/bin/python3
NP ?= 2
MPIRUN ?= mpirun
OUT ?= results
TEST_TIMEOUT ?= 1500
export OMPI_ALLOW_RUN_AS_ROOT = 1
export OMPI_ALLOW_RUN_AS_ROOT_CONFIRM = 1
export OMPI_MCA_rmaps_base_oversubscribe = 1
export OMP_NUM_THREADS = 1
export PYTHONDONTWRITEBYTECODE = 1

DEB_PACKAGES = python3-dolfinx-real python3-numba python3-scipy python3-pytest \
	python3-matplotlib python3-gmsh python3-h5py mpi-default-bin openmpi-bin \
	xvfb xauth python3-paraview python3-hypothesis
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
DEBIAN13 ?= ../shared/tools/debian13-env.sh
DEBIAN13_PKGS = python3-matplotlib python3-gmsh python3-h5py python3-hypothesis

.PHONY: deps demo test test-debian13 benchmark clean

deps:
	@missing=$$(for p in $(DEB_PACKAGES); do dpkg-query -W -f='$${Status}\n' $$p 2>/dev/null | grep -q "ok installed" || echo $$p; done); \
	if [ -n "$$missing" ]; then \
		echo "installing Debian packages: $$missing"; \
		$(SUDO) apt-get update -q && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -q --no-install-recommends $$missing; \
	fi

demo: deps
	$(MPIRUN) -n $(NP) $(PYTHON) demos/hole_plate.py --out $(OUT)/hole_plate
	$(MPIRUN) -n $(NP) $(PYTHON) demos/shear_layer.py --out $(OUT)/shear_layer
	$(PYTHON) demos/material_point.py --test all --out $(OUT)/material_point
	$(PYTHON) demos/identify.py --out $(OUT)/identify
	$(PYTHON) demos/dem_cell.py --out $(OUT)/dem_cell
	$(MPIRUN) -n $(NP) $(PYTHON) demos/biaxial.py --out $(OUT)/biaxial
	$(MPIRUN) -n $(NP) $(PYTHON) demos/femdem_biaxial.py --axial-strain 0.03 --steps 30 --out $(OUT)/femdem_biaxial

test: deps
	NP=$(NP) TEST_TIMEOUT=$(TEST_TIMEOUT) tests/run_suite.sh $(PYTHON)

# the same suite against dolfinx 0.9 in a Debian 13 chroot (root only; builds it once)
test-debian13:
	@if [ ! -x "$(DEBIAN13)" ]; then \
		echo "$(DEBIAN13) not found (set DEBIAN13=path/to/debian13-env.sh): Debian 13 pass skipped"; \
	else \
		$(DEBIAN13) --extra-pkgs "$(DEBIAN13_PKGS)" --bind-rw "$(CURDIR)":/srv/project --workdir /srv/project \
			-- sh tests/run_suite.sh python3; \
	fi

# figures, not tests; YADE is only needed here (DEM speed and cross-check)
BENCH_PACKAGES = yade python3-escript
benchmark: deps
	@missing=$$(for p in $(BENCH_PACKAGES); do dpkg-query -W -f='$${Status}\n' $$p 2>/dev/null | grep -q "ok installed" || echo $$p; done); \
	if [ -n "$$missing" ]; then $(SUDO) apt-get update -q && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -q --no-install-recommends $$missing; fi
	$(PYTHON) benchmarks/convergence.py --np $(NP) --out $(OUT)/benchmarks
	$(PYTHON) benchmarks/ehlers_kernel_throughput.py --json $(OUT)/benchmarks/ehlers_kernel_throughput.json
	$(PYTHON) benchmarks/dem_speed.py --out $(OUT)/benchmarks/dem_speed
	$(PYTHON) benchmarks/dem_profile.py --identity --out $(OUT)/benchmarks/dem_profile
	$(PYTHON) benchmarks/dem_tangent.py --out $(OUT)/benchmarks/dem_tangent
	$(PYTHON) benchmarks/dem_relaxation.py --out $(OUT)/benchmarks/dem_relaxation
	$(PYTHON) benchmarks/dem_micropolar_moduli.py --out $(OUT)/benchmarks/dem_micropolar_moduli
	$(PYTHON) benchmarks/softening_layer.py --out $(OUT)/benchmarks/softening_layer
	$(PYTHON) benchmarks/biaxial_regularisation.py --out $(OUT)/benchmarks/biaxial_regularisation
	$(PYTHON) benchmarks/biaxial_convergence.py --out $(OUT)/benchmarks/biaxial_convergence
	$(PYTHON) benchmarks/biaxial_profile.py --out $(OUT)/benchmarks/biaxial_profile
	$(MPIRUN) -n $(NP) $(PYTHON) benchmarks/biaxial_profile.py --out $(OUT)/benchmarks/biaxial_profile_np$(NP)
	$(MPIRUN) -n $(NP) $(PYTHON) benchmarks/femdem_tangents.py --mesh 1x2 --out $(OUT)/benchmarks/femdem_tangents
	$(MPIRUN) -n $(NP) $(PYTHON) benchmarks/femdem_regularisation.py --out $(OUT)/benchmarks/femdem_regularisation
	$(MPIRUN) -n $(NP) $(PYTHON) benchmarks/femdem_convergence.py --out $(OUT)/benchmarks/femdem_convergence
	$(MPIRUN) -n $(NP) $(PYTHON) benchmarks/femdem_rotation.py --out $(OUT)/benchmarks/femdem_rotation
	$(MPIRUN) -n $(NP) $(PYTHON) benchmarks/femdem_micropolar.py --out $(OUT)/benchmarks/femdem_micropolar
	$(MPIRUN) -n $(NP) $(PYTHON) benchmarks/femdem_balance.py --out $(OUT)/benchmarks/femdem_balance
	$(PYTHON) benchmarks/femdem_scaling.py --out $(OUT)/benchmarks/femdem_scaling
	$(PYTHON) benchmarks/femdem_batched.py --out $(OUT)/benchmarks/femdem_batched
	$(MPIRUN) -n $(NP) $(PYTHON) benchmarks/femdem_cell_relaxation.py --out $(OUT)/benchmarks/femdem_cell_relaxation
	$(PYTHON) benchmarks/femdem_yade.py --np $(NP) --out $(OUT)/benchmarks/femdem_yade
	$(PYTHON) benchmarks/identification_sensitivity.py --out $(OUT)/benchmarks/identification_sensitivity
	$(PYTHON) benchmarks/identification_cost.py --out $(OUT)/benchmarks/identification_cost
	$(PYTHON) benchmarks/reidentification.py --draws 100 --out $(OUT)/benchmarks/reidentification
	$(PYTHON) benchmarks/reidentification.py --steps 4800 --every 80 --model-min-steps 600 --draws 40 --out $(OUT)/benchmarks/reidentification_steps
	$(PYTHON) benchmarks/skew_stress_cost.py --out $(OUT)/benchmarks/skew_stress_cost
	$(PYTHON) benchmarks/identify_micropolar.py --out $(OUT)/benchmarks/identify_micropolar
	$(PYTHON) benchmarks/dem_virtual_tests.py --out $(OUT)/benchmarks/dem_virtual_tests
	$(PYTHON) benchmarks/dem_calibration.py --dem $(OUT)/benchmarks/dem_virtual_tests --out $(OUT)/benchmarks/dem_calibration
	$(PYTHON) benchmarks/femdem_vs_ehlers.py --parameters $(OUT)/benchmarks/dem_calibration/identify/identified_parameters.json --out $(OUT)/benchmarks/femdem_vs_ehlers
	$(PYTHON) benchmarks/robustness_sweep.py --random 2 --out $(OUT)/benchmarks/robustness_sweep
	$(PYTHON) benchmarks/damaged_inputs.py --per-kind 80 --restarts 20 --out $(OUT)/benchmarks/damaged_inputs
	DAMAGE_EXAMPLES=40 DAMAGE_RANDOM=1 $(PYTHON) -m pytest -q -p no:cacheprovider tests/test_damaged_inputs.py
	$(PYTHON) benchmarks/interrupt_runs.py --trials 12 --ranks $(NP) --signal INT --out $(OUT)/benchmarks/interrupt_runs
	ROBUSTNESS_EXAMPLES=25 ROBUSTNESS_RANDOM=1 $(PYTHON) -m pytest -q -p no:cacheprovider tests/test_robustness_properties.py
	$(PYTHON) -m pytest -q -p no:cacheprovider -m slow tests

clean:
	rm -rf $(OUT) .pytest_cache
	find . -name __pycache__ -prune -exec rm -rf {} +
