# The two set-up commands of the README: `make demo` and `make test`.
# Each creates/updates the virtual environment, installs the project and the system packages
# it needs (as root; otherwise it prints the apt-get command), then runs its job.

PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# torch is pinned to the CPU build in constraints.txt (the one place), not in pyproject.toml.
CONSTRAINTS := constraints.txt
SYSTEM_PACKAGES := xvfb xauth xdotool x11-utils libegl1 libgl1 libegl-mesa0 libgl1-mesa-dri libgles2 \
	chromium chromium-driver
PYTEST_ARGS ?=
# Installed without their declared dependencies, which would pull torchvision (it cannot be
# imported beside the pinned CPU torch) and, for cvvdp, a PyPI package named 'ffmpeg' that
# clashes with ffmpeg-python: ColorVideoVDP (the cvvdp peer metric; MIT) and PIQ (the
# reference the tests check the image metrics against; Apache-2.0, test-only).
NO_DEPS_PACKAGES := cvvdp==0.5.7 piq==0.8.0

.PHONY: demo test test-slow lint docs install system-deps clean participant-app

DEMO_ARGS ?=

demo: install
	$(BIN)/python scripts/run_demo.py --out demo_output $(DEMO_ARGS)

test: install
	$(BIN)/python -m pytest $(PYTEST_ARGS)

test-slow: install
	$(BIN)/python -m pytest -m slow $(PYTEST_ARGS)

lint: install
	$(BIN)/ruff check .

# The documentation site (docs/, mkdocs.yml) into site/; strict: a warning fails the build.
docs: install
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --quiet
	@echo "documentation: site/index.html"

install: system-deps $(STAMP)

$(STAMP): pyproject.toml $(CONSTRAINTS)
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -c $(CONSTRAINTS) -e '.[all,dev]'
	$(BIN)/python -m pip install --quiet --no-deps -c $(CONSTRAINTS) $(NO_DEPS_PACKAGES)
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

# The frozen participant app (PyInstaller, one folder): built from the base install only, in a
# virtual environment of its own, so nothing of the research stack can slip in.
APP_VENV := build/participant-venv
participant-app: system-deps
	@test -x $(APP_VENV)/bin/python || $(PYTHON) -m venv $(APP_VENV)
	$(APP_VENV)/bin/python -m pip install --quiet --upgrade pip
	$(APP_VENV)/bin/python -m pip install --quiet . 'pyinstaller>=6.10'
	$(APP_VENV)/bin/pyinstaller --noconfirm --log-level WARN --distpath dist \
		--workpath build/pyinstaller packaging/cgvq-study.spec
	@du -sh dist/cgvq-study | awk '{print "participant app: dist/cgvq-study (" $$1 ")"}'

clean:
	rm -rf $(VENV) demo_output .pytest_cache .ruff_cache *.egg-info build dist site
