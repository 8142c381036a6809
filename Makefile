# The two set-up commands of the README: `make demo` and `make test`.
# Each creates/updates the virtual environment, installs the project and the system packages
# it needs (as root; otherwise it prints the apt-get command), then runs its job.

PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
SYSTEM_PACKAGES := xvfb xauth xdotool x11-utils libegl1 libgl1 libegl-mesa0 libgl1-mesa-dri libgles2
PYTEST_ARGS ?=

.PHONY: demo test test-slow lint install system-deps clean

DEMO_ARGS ?=

demo: install
	$(BIN)/python scripts/run_demo.py --out demo_output $(DEMO_ARGS)

test: install
	$(BIN)/python -m pytest $(PYTEST_ARGS)

test-slow: install
	$(BIN)/python -m pytest -m slow $(PYTEST_ARGS)

lint: install
	$(BIN)/ruff check .

install: system-deps $(STAMP)

$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	@touch $(STAMP)

system-deps:
	@missing=""; \
	for p in $(SYSTEM_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -z "$$missing" ]; then exit 0; fi; \
	if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
		echo "installing system packages:$$missing"; \
		apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends $$missing >/dev/null; \
	else \
		echo "System packages missing (GUI tests will be skipped):$$missing"; \
		echo "Install them with:  sudo apt-get install -y$$missing"; \
	fi

clean:
	rm -rf $(VENV) demo_output .pytest_cache .ruff_cache *.egg-info
