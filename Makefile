# Everything a user needs: `make demo` and `make test` each set themselves up on a fresh machine.
SHELL := /bin/bash
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

# LeRobot >= 0.5 needs Python 3.12: look on PATH first, then in pyenv's versions directory.
PYTHON ?= $(shell for p in python3.12 $${PYENV_ROOT:-$$HOME/.pyenv}/versions/3.12*/bin/python3.12 \
	/root/.pyenv/versions/3.12*/bin/python3.12 /usr/local/bin/python3.12 /usr/bin/python3.12; do \
	if "$$p" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 12))' >/dev/null 2>&1; then \
	command -v "$$p"; break; fi; done)

export MUJOCO_GL ?= egl
export HF_HUB_OFFLINE ?= 1
export TOKENIZERS_PARALLELISM ?= false

.PHONY: setup test test-fast lint demo clean

setup: $(STAMP)

$(STAMP): pyproject.toml
	@if [ -z "$(PYTHON)" ]; then echo "error: Python 3.12 not found (PATH or pyenv versions directory)" >&2; exit 1; fi
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[dev]"
	@touch $(STAMP)

lint: setup
	$(BIN)/ruff check lerobot_kvm tests lerobot_policy_coda_kvm.py

test: setup lint
	$(BIN)/python -m pytest -q tests

test-fast: setup
	$(BIN)/python -m pytest -q -m "not slow" tests

# The benchmark's short form: record -> continual pretraining (lerobot-train) -> challenge protocol -> report.
demo: setup
	$(BIN)/lerobot-kvm benchmark --config configs/benchmark_quick.json --output-dir outputs/demo

clean:
	rm -rf $(VENV) outputs
