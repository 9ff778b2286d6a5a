# feed_twin: `make demo` and `make test` are the only commands a fresh Debian 12 machine needs.
# Both run the idempotent set-up first (tools/setup.sh: .venv, pinned dependencies, msgs/).

VENV := .venv
BIN := $(VENV)/bin
PYTEST_ARGS ?=

.PHONY: setup test test-fast demo bench

setup:
	@bash tools/setup.sh

# ruff and pytest all run even when one fails, so the pytest summary line is always printed;
# pytest's exit 5 ("no tests collected") counts as success.
test: setup
	@bash tools/run_tests.sh $(PYTEST_ARGS)

test-fast: setup
	@bash tools/run_tests.sh -m "not slow" $(PYTEST_ARGS)

# The demo: a G-code program through the three ROS 2 nodes, recorded to bags/ (MCAP + .rrd).
DEMO_CONFIG ?= config/axis_default.yaml
DEMO_PROGRAM ?= tests/fixtures/gcode/sample.ngc

demo: setup
	@echo "demo: $(DEMO_PROGRAM) through the ROS 2 node set (G-code node -> controller"
	@echo "demo: node -> simulated axis, three processes), recorded to bags/ with a Rerun .rrd"
	@$(BIN)/feed-twin run "$(DEMO_PROGRAM)" --config "$(DEMO_CONFIG)"

# benchmarks/_*.py are helpers that a benchmark runs itself (e.g. under another interpreter).
bench: setup
	@status=0; found=0; \
	for script in benchmarks/*.py; do \
		[ -e "$$script" ] || continue; \
		case "$${script##*/}" in _*) continue ;; esac; found=1; \
		echo "== $$script"; \
		$(BIN)/python "$$script" || { echo "bench: $$script failed"; status=1; }; \
	done; \
	[ $$found -eq 1 ] || echo "bench: no benchmarks/*.py yet"; \
	exit $$status
