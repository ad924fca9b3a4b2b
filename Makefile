# One entry point for set-up, tests and the demo. Every target refreshes .venv first.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.setup-done
TORCH_VERSION ?= 2.13.0

.PHONY: setup test test-slow demo bench clean

setup: $(STAMP)

$(STAMP): pyproject.toml scripts/setup.sh
	TORCH_VERSION=$(TORCH_VERSION) PY=$(PY) bash scripts/setup.sh
	touch $(STAMP)

test: setup
	$(BIN)/python -m pytest -q

test-slow: setup
	$(BIN)/python -m pytest -q -m slow

demo: setup
	$(BIN)/recon demo

bench: setup
	$(BIN)/recon bench fusion

clean:
	rm -rf $(VENV) build *.egg-info
