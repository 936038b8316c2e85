# Two commands do everything on a fresh machine: `make demo` and `make test`.
# Each bootstraps .venv (Python >= 3.11 with venv) and installs the package with
# its extras; a stamp file re-runs the install when the packaging changes.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-roi-node
EXTRAS := ros,bag,robots,export,sign,cluster,openpi,dev
OPENPI_CLIENT := openpi-client==0.1.2
DEMO_OUT ?= demo_out

# Everything that starts DDS keeps it on this machine, on its own domain.
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST
# glibc settings that cut page faults for large image messages (roi_node/util/process_memory.py says why)
export MALLOC_MMAP_THRESHOLD_ := 33554432
export MALLOC_TRIM_THRESHOLD_ := 4000000000

.PHONY: test test-fast test-lerobot demo bench lint docs venv clean

venv: $(STAMP)

$(STAMP): setup.py setup.cfg package.xml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[$(EXTRAS)]"
	$(PY) -m pip install --quiet --no-deps "$(OPENPI_CLIENT)"  # its numpy<2 pin: setup.py's openpi extra says why
	touch $(STAMP)

test: $(STAMP)
	$(PY) -m compileall -q roi_node test examples  # a cold first import must not slow the first live test
	$(PY) -c "from roi_node.engine.area_resample import warm_up; warm_up()"  # nor the resampling kernels' first JIT compile
	# two workers, each test module whole on one (its fixtures built once, test/conftest.py); DDS tests take domains
	# from their worker's own block of ROS_DOMAIN_ID.. (test/dds/harness.py), so two of them never hear each other
	# a run that hangs anyway is interrupted after 40 min (pytest then prints what failed) rather than at CI's limit
	# --durations: the 25 slowest tests close the output, where a run that grew slower shows it
	ROS_DOMAIN_ID=$${ROS_DOMAIN_ID:-71} timeout -s INT -k 60 2400 $(PY) -m pytest -q -n 2 --dist loadgroup --durations=25 test

# The edit loop: everything but the DDS, Ray, colcon and demo tests and the slowest of the rest (markers dds, ray and
# slow; see pyproject.toml).
test-fast: $(STAMP)
	$(PY) -c "from roi_node.engine.area_resample import warm_up; warm_up()"
	$(PY) -m pytest -q -n 2 --dist loadgroup -m "not dds and not ray and not slow" test

# Opt-in, not part of `make test`: the real LeRobot reader (lerobot pulls torch, several GB) in its own
# venv loads what `roi-node export lerobot` writes. Offline: nothing is fetched from the Hub.
LEROBOT_VENV := .venv-lerobot
LEROBOT_STAMP := $(LEROBOT_VENV)/.installed-lerobot
LEROBOT_VERSION ?= 0.4.4

$(LEROBOT_STAMP): setup.py setup.cfg package.xml
	$(PYTHON) -m venv $(LEROBOT_VENV)
	$(LEROBOT_VENV)/bin/python -m pip install --quiet --upgrade pip
	# ros: the live parity test (test/datasets/lerobot/test_policy_parity.py) and a LeRobot policy fed by a running node need rclpy
	# async: LeRobot's PolicyServer, which the grpc:// test (test/datasets/lerobot/test_policy_grpc.py) runs
	$(LEROBOT_VENV)/bin/python -m pip install --quiet "lerobot[async]==$(LEROBOT_VERSION)" -e ".[ros,bag,robots,export,grpc]" pytest pytest-timeout
	# the placo that resolves next to lerobot's pins links urdfdom 4 and tinyxml2 10, which its metadata does not enforce
	$(LEROBOT_VENV)/bin/python -m pip install --quiet "cmeel-urdfdom<5" "cmeel-tinyxml2<11"
	touch $(LEROBOT_STAMP)

test-lerobot: $(LEROBOT_STAMP)
	hf_home=$$(mktemp -d) && trap 'rm -rf "$$hf_home"' EXIT && \
		HF_HUB_OFFLINE=1 HF_DATASETS_OFFLINE=1 HF_HOME=$$hf_home ROI_NODE_LEROBOT_TESTS=1 ROS_DOMAIN_ID=$${ROS_DOMAIN_ID:-74} \
		$(LEROBOT_VENV)/bin/python -m pytest -q -p no:cacheprovider test/datasets/lerobot

demo: $(STAMP)
	$(PY) -m compileall -q roi_node
	$(PY) -c "from roi_node.engine.area_resample import warm_up; warm_up()"
	ROS_DOMAIN_ID=$${ROS_DOMAIN_ID:-72} $(VENV)/bin/roi-node demo --out $(DEMO_OUT)

bench: $(STAMP)
	$(PY) bench/core.py
	$(PY) bench/sim.py
	$(PY) bench/replay.py
	$(PY) bench/validate.py
	$(PY) bench/bagwrite.py
	$(PY) bench/export.py
	$(PY) bench/calibration.py
	$(PY) bench/offset.py
	$(PY) bench/jpeg.py
	$(PY) bench/overlay.py
	$(PY) bench/ray.py
	$(PY) bench/record_preset.py
	ROS_DOMAIN_ID=$${ROS_DOMAIN_ID:-73} $(PY) bench/live.py
	$(PY) bench/live_independent.py --domain $$(( $${ROS_DOMAIN_ID:-73} + 4 ))
	$(PY) bench/live_agreement.py --domain $$(( $${ROS_DOMAIN_ID:-73} + 8 ))
	$(PY) bench/live_overload.py --domain $$(( $${ROS_DOMAIN_ID:-73} + 2 ))
	$(PY) bench/policy.py --domain $$(( $${ROS_DOMAIN_ID:-73} + 6 )) --policies callable  # ACT: run it with .venv-lerobot/bin/python
	$(PY) bench/live_cpu.py --domain $$(( $${ROS_DOMAIN_ID:-73} + 14 )) --executors single
	ROS_DOMAIN_ID=$$(( $${ROS_DOMAIN_ID:-73} + 17 )) $(PY) bench/live_wait_set.py
	ROS_DOMAIN_ID=$$(( $${ROS_DOMAIN_ID:-73} + 18 )) $(PY) bench/live_take.py

# docs/rig-config.md's key table from config/rig.schema.json (test/rig/test_rig_doc.py fails when it is stale)
docs: $(STAMP)
	$(PY) -m roi_node.rig.rig_doc docs/rig-config.md

lint: $(STAMP)
	$(VENV)/bin/ruff check roi_node test bench examples
	$(VENV)/bin/mypy roi_node

clean:
	rm -rf $(VENV) $(LEROBOT_VENV) $(DEMO_OUT) build install log
