# make demo | make test | make test-fast | make bench | make bags | make docs   (each sets up .venv first)
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST
export RMW_IMPLEMENTATION ?= rmw_fastrtps_cpp

CHROMIUM := /usr/bin/chromium
# make demo HMI_LINGER=600 keeps the graph and its HMI page up 10 min after the replay
HMI_LINGER ?= 0

.PHONY: setup lint test test-fast demo bench bags docs clean

$(VENV)/.installed: requirements.txt setup.py
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r requirements.txt
	$(PY) -m pip install --quiet --no-deps -e .
	touch $@

setup: $(VENV)/.installed

# Debian's chromium for the HMI's browser test and screenshot (Playwright downloads no browser here)
$(CHROMIUM):
	@if [ "$$(id -u)" = 0 ]; then \
		apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium fonts-dejavu-core >/dev/null; \
	else echo "make: the HMI browser test needs Debian's chromium: sudo apt-get install chromium fonts-dejavu-core" >&2; fi

lint: setup
	$(VENV)/bin/ruff check hydro_ros test launch bench scripts
	$(VENV)/bin/mypy

# every tier, what CI runs. The live-graph tests one after another (nodes in real time, never two sets at once); beside
# them the library and browser tests on two workers at nice 5, so the nodes' real-time work comes first and the library
# takes what the two cores have left (all on two workers took 13 min here, this 11); each run on ROS domains of its own.
# Then the CAN bridge's bus tests alone (the "solo" mark): their frames over UDP multicast are lost whenever anything else runs
# the three runs build a fixture they share once (test/conftest.py built_once), in a folder emptied first
test: export HYDRO_ROS_TEST_SHARED = $(CURDIR)/out/test-shared
test: lint $(CHROMIUM)
	@rm -rf out/test-shared; mkdir -p out/test-shared; echo "the live-graph tests run beside these; their report follows (out/test-live.log)"; \
	TEST_ROS_DOMAINS=10-119 $(PY) -m pytest -q -p no:cacheprovider --durations=12 -m "ros_graph and not browser and not solo" test \
		> out/test-live.log 2>&1 & live=$$!; \
	TEST_ROS_DOMAINS=120-229 nice -n 5 $(PY) -m pytest -q -n 2 --durations=12 -m "(not ros_graph or browser) and not solo" test; library=$$?; \
	wait $$live; graph=$$?; cat out/test-live.log; [ $$library = 0 ] && [ $$graph = 0 ]
	$(PY) -m pytest -q --durations=12 -m solo test

# the library tests without a ROS graph, a browser or a long study: the loop while changing code
test-fast: lint
	$(PY) -m pytest -q -n 2 -m "not ros_graph and not browser and not slow" test

demo: setup
	ROS_DOMAIN_ID=$${ROS_DOMAIN_ID:-42} $(VENV)/bin/hydro-ros demo --out out/demo --linger $(HMI_LINGER)

# every benchmark (hydro_ros/tooling/benchrun.py), each result file stamped with the commit and the code it ran on; a step whose files
# already hold the code as it is is skipped, so an interrupted run goes on where it stopped. Refused on uncommitted code
# unless ALLOW_DIRTY=1. BENCH_ARGS: --force (rerun all), --only NAME, --list, --dask local or --dask tcp://HOST:8786
bench: setup $(CHROMIUM)
	$(PY) -m hydro_ros.tooling.benchrun $(if $(filter 1,$(ALLOW_DIRTY)),--allow-dirty) $(BENCH_ARGS)

docs: setup
	$(PY) -m hydro_ros.tooling.docgen docs

bags: setup
	$(PY) scripts/make_sample_bags.py --out bags

clean:
	rm -rf build install log out .pytest_cache
