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
# the project's packages (cosserat_fenicsx, demcell, benchmarks) for every script and test
export PYTHONPATH := $(CURDIR)$(if $(PYTHONPATH),:$(PYTHONPATH))

DEB_PACKAGES = python3-dolfinx-real python3-numba python3-scipy python3-pytest \
	python3-matplotlib python3-gmsh python3-h5py mpi-default-bin openmpi-bin \
	xvfb xauth python3-paraview python3-hypothesis python3-pytest-xdist lammps python3-lammps
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
DEBIAN13 ?= ../shared/tools/debian13-env.sh
DEBIAN13_PKGS = python3-matplotlib python3-gmsh python3-h5py python3-hypothesis python3-pytest-xdist

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
	$(PYTHON) demos/dem_specimen.py --nx 30 --ny 69 --duration 90 --snapshots 0,30,60,90 --out $(OUT)/dem_specimen
	$(PYTHON) demos/dem_specimen.py --specimen tiled --tiles 1x2 --axial-strain 0.02 --out $(OUT)/dem_specimen_tiled
	$(MPIRUN) -n $(NP) $(PYTHON) demos/footing_bsm.py --packing A --out $(OUT)/footing_bsm_A

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

# figures, not tests (benchmarks/README.md: what each script measures, its runtime, its docs page);
# YADE is only needed here (DEM speed and the FEM x DEM cross-check)
BENCH_PACKAGES = yade python3-escript
BENCH = $(OUT)/benchmarks
BENCHMARK_GROUPS = verification ehlers dem femdem dns bsm identification robustness slow-tests
.PHONY: benchmark-deps $(BENCHMARK_GROUPS:%=benchmark-%)

benchmark: $(BENCHMARK_GROUPS:%=benchmark-%)

benchmark-deps: deps
	@missing=$$(for p in $(BENCH_PACKAGES); do dpkg-query -W -f='$${Status}\n' $$p 2>/dev/null | grep -q "ok installed" || echo $$p; done); \
	if [ -n "$$missing" ]; then $(SUDO) apt-get update -q && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -q --no-install-recommends $$missing; fi

benchmark-verification: benchmark-deps
	$(PYTHON) benchmarks/verification/convergence.py --np $(NP) --out $(BENCH)
	$(PYTHON) benchmarks/verification/explicit_dynamics.py --out $(BENCH)/explicit_dynamics

benchmark-ehlers: benchmark-deps
	$(PYTHON) benchmarks/ehlers/ehlers_kernel_throughput.py --json $(BENCH)/ehlers_kernel_throughput.json
	$(PYTHON) benchmarks/ehlers/softening_layer.py --out $(BENCH)/softening_layer
	$(PYTHON) benchmarks/ehlers/biaxial_regularisation.py --out $(BENCH)/biaxial_regularisation
	$(PYTHON) benchmarks/ehlers/biaxial_convergence.py --out $(BENCH)/biaxial_convergence
	$(PYTHON) benchmarks/ehlers/biaxial_profile.py --out $(BENCH)/biaxial_profile
	$(MPIRUN) -n $(NP) $(PYTHON) benchmarks/ehlers/biaxial_profile.py --out $(BENCH)/biaxial_profile_np$(NP)
	$(PYTHON) benchmarks/ehlers/skew_stress_cost.py --out $(BENCH)/skew_stress_cost

# the calibration chain ends here: virtual tests on the DEM cell, the Ehlers parameters identified
# from them, then the calibrated Ehlers biaxial against the FEM x DEM one (which reads them)
benchmark-dem: benchmark-deps
	$(PYTHON) benchmarks/dem/dem_speed.py --out $(BENCH)/dem_speed
	$(PYTHON) benchmarks/dem/dem_profile.py --identity --out $(BENCH)/dem_profile
	$(PYTHON) benchmarks/dem/dem_tangent.py --out $(BENCH)/dem_tangent
	$(PYTHON) benchmarks/dem/dem_relaxation.py --out $(BENCH)/dem_relaxation
	$(PYTHON) benchmarks/dem/dem_micropolar_moduli.py --out $(BENCH)/dem_micropolar_moduli
	$(PYTHON) benchmarks/dem/dem_virtual_tests.py --out $(BENCH)/dem_virtual_tests
	$(PYTHON) benchmarks/dem/frame_cell.py --increments 5 --out $(BENCH)/frame_cell
	$(PYTHON) benchmarks/dem/dem_calibration.py --dem $(BENCH)/dem_virtual_tests --out $(BENCH)/dem_calibration
	$(PYTHON) benchmarks/femdem/femdem_vs_ehlers.py --parameters $(BENCH)/dem_calibration/identify/identified_parameters.json --out $(BENCH)/femdem_vs_ehlers

benchmark-femdem: benchmark-deps
	$(MPIRUN) -n $(NP) $(PYTHON) benchmarks/femdem/femdem_tangents.py --mesh 1x2 --out $(BENCH)/femdem_tangents
	$(MPIRUN) -n $(NP) $(PYTHON) benchmarks/femdem/femdem_regularisation.py --out $(BENCH)/femdem_regularisation
	$(MPIRUN) -n $(NP) $(PYTHON) benchmarks/femdem/femdem_convergence.py --out $(BENCH)/femdem_convergence
	$(MPIRUN) -n $(NP) $(PYTHON) benchmarks/femdem/femdem_rotation.py --out $(BENCH)/femdem_rotation
	mkdir -p $(BENCH) && $(PYTHON) benchmarks/femdem/femdem_operator_spectrum.py > $(BENCH)/femdem_operator_spectrum.txt
	$(MPIRUN) -n $(NP) $(PYTHON) benchmarks/femdem/femdem_micropolar.py --out $(BENCH)/femdem_micropolar
	$(MPIRUN) -n $(NP) $(PYTHON) benchmarks/femdem/femdem_balance.py --out $(BENCH)/femdem_balance
	$(PYTHON) benchmarks/femdem/femdem_scaling.py --out $(BENCH)/femdem_scaling
	$(PYTHON) benchmarks/femdem/femdem_batched.py --out $(BENCH)/femdem_batched
	$(MPIRUN) -n $(NP) $(PYTHON) benchmarks/femdem/femdem_cell_relaxation.py --out $(BENCH)/femdem_cell_relaxation
	$(PYTHON) benchmarks/femdem/femdem_yade.py --np $(NP) --out $(BENCH)/femdem_yade
	$(MPIRUN) -n $(NP) $(PYTHON) benchmarks/femdem/femdem_residual_floor.py --out $(BENCH)/femdem_residual_floor
	$(MPIRUN) -n $(NP) $(PYTHON) benchmarks/femdem/femdem_residual_noise.py --out $(BENCH)/femdem_residual_noise

# particle specimens: throughput, the 004 test and its study, LAMMPS on the same specimen, the
# full-DEM footing of 003, the tiled-cell DNS against FEM x DEM (000)
benchmark-dns: benchmark-deps
	$(PYTHON) benchmarks/dns/specimen_throughput.py --out $(BENCH)/specimen_throughput
	$(PYTHON) benchmarks/dns/lammps_compare.py --out $(BENCH)/lammps_compare
	$(PYTHON) benchmarks/dns/dns_004.py --cases base --out $(BENCH)/dns_004
	$(PYTHON) benchmarks/dns/dns_004.py --nx 40 --ny 92 --out $(BENCH)/dns_004_study
	$(PYTHON) benchmarks/dns/footing_dem.py --packing A --out $(BENCH)/footing_dem_A
	$(PYTHON) benchmarks/dns/footing_dem.py --packing C --out $(BENCH)/footing_dem_C
	$(PYTHON) benchmarks/dns/dns_vs_femdem.py --out $(BENCH)/dns_vs_femdem
	$(PYTHON) benchmarks/dns/dns_band.py --cases dns-2x4 --out $(BENCH)/dns_band
	@if [ ! -f $(BENCH)/dem_calibration/identify/identified_parameters.json ]; then \
		$(PYTHON) benchmarks/dem/dem_virtual_tests.py --out $(BENCH)/dem_virtual_tests && \
		$(PYTHON) benchmarks/dem/dem_calibration.py --dem $(BENCH)/dem_virtual_tests --out $(BENCH)/dem_calibration; fi
	$(MPIRUN) -n $(NP) $(PYTHON) benchmarks/dns/continuum_bands.py --dns $(BENCH)/dns_band \
		--parameters $(BENCH)/dem_calibration/identify/identified_parameters.json --out $(BENCH)/continuum_bands
	$(PYTHON) benchmarks/dns/band_couple_stress.py --dns $(BENCH)/dns_band --continua $(BENCH)/continuum_bands \
		--out $(BENCH)/band_couple_stress
	$(PYTHON) benchmarks/dns/band_trends.py --models dns --out $(BENCH)/band_trends
	$(MPIRUN) -n $(NP) $(PYTHON) benchmarks/dns/band_trends.py --models hybrid,micropolar --out $(BENCH)/band_trends
	$(PYTHON) benchmarks/dns/band_trends.py --report-only --out $(BENCH)/band_trends

# the bridging-scale method (paper 003): ghost forces, a pulse across the interface, the
# elastic FE footing, and the footing against the full DEM of the same grains
benchmark-bsm: benchmark-deps
	$(PYTHON) benchmarks/bsm/patch_test.py --radius 0.1 0.05 0.025 0.0125 --out $(BENCH)/bsm_patch
	$(PYTHON) benchmarks/bsm/patch_drift.py --out $(BENCH)/bsm_patch_drift
	$(PYTHON) benchmarks/bsm/wave.py --out $(BENCH)/bsm_wave
	$(PYTHON) benchmarks/bsm/footing_fe.py --out $(BENCH)/bsm_footing_fe
	$(PYTHON) benchmarks/bsm/footing_compare.py --out $(BENCH)/bsm_footing_compare
	OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 $(PYTHON) benchmarks/bsm/footing_compare.py --cases A:003:10 B:003:10 C:003:10 A:003:10:1.0:54 --repeat 4 --out $(BENCH)/bsm_cost
	OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 $(PYTHON) benchmarks/bsm/footing_compare.py --gravity 9.81 --depth 0.03 --settlements 5 10 15 20 25 --error-range 2 20 --cases A:lattice-cubic:10:0.1 A:lattice-cubic:10:0.1:18:8x4 A:lattice-cubic:10:0.1:18:10x5 A:lattice-cubic:10:0.1:18:12x6 A:lattice-cubic:10:0.1:18:14x7 A:lattice-coulomb:10:0.1 --out $(BENCH)/bsm_gravity
	for v in 0.2 0.1 0.05 0.025; do OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 $(PYTHON) benchmarks/dns/footing_dem.py --packing A --gravity 9.81 --depth 0.03 --speed $$v --out $(BENCH)/bsm_gravity_rate/dem_$$v || exit 1; done
	$(PYTHON) benchmarks/bsm/footing_rate.py $(BENCH)/bsm_gravity_rate/dem_0.2 $(BENCH)/bsm_gravity_rate/dem_0.1 $(BENCH)/bsm_gravity_rate/dem_0.05 $(BENCH)/bsm_gravity_rate/dem_0.025 --from 2 --to 25

benchmark-identification: benchmark-deps
	$(PYTHON) benchmarks/identification/identification_sensitivity.py --out $(BENCH)/identification_sensitivity
	$(PYTHON) benchmarks/identification/identification_cost.py --out $(BENCH)/identification_cost
	$(PYTHON) benchmarks/identification/reidentification.py --draws 100 --out $(BENCH)/reidentification
	$(PYTHON) benchmarks/identification/reidentification.py --steps 4800 --every 80 --model-min-steps 600 --draws 40 --out $(BENCH)/reidentification_steps
	$(PYTHON) benchmarks/identification/identify_micropolar.py --out $(BENCH)/identify_micropolar

benchmark-robustness: benchmark-deps
	$(PYTHON) benchmarks/robustness/robustness_sweep.py --random 2 --out $(BENCH)/robustness_sweep
	$(PYTHON) benchmarks/robustness/damaged_inputs.py --per-kind 80 --restarts 20 --out $(BENCH)/damaged_inputs
	DAMAGE_EXAMPLES=40 DAMAGE_RANDOM=1 $(PYTHON) -m pytest -q -p no:cacheprovider tests/test_damaged_inputs.py
	$(PYTHON) benchmarks/robustness/interrupt_runs.py --trials 12 --ranks $(NP) --signal INT --out $(BENCH)/interrupt_runs
	ROBUSTNESS_EXAMPLES=25 ROBUSTNESS_RANDOM=1 $(PYTHON) -m pytest -q -p no:cacheprovider tests/test_robustness_properties.py

# the tests marked slow (too long for make test)
benchmark-slow-tests: benchmark-deps
	$(PYTHON) -m pytest -q -p no:cacheprovider -m slow tests

clean:
	rm -rf $(OUT) .pytest_cache
	find . -name __pycache__ -prune -exec rm -rf {} +
