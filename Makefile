# The two commands a new user needs: `make demo` and `make test`.
SHELL := /bin/bash
VENV := .venv
PY := $(VENV)/bin/python
DEMO_OUT ?= out/demo

.PHONY: setup demo test bench clean-venv

setup:
	@bash tools/setup_env.sh

demo: setup
	$(VENV)/bin/bijcr run scenes/demo --out $(DEMO_OUT)

test: setup
	$(PY) -m pytest -q -p no:cacheprovider -p no:dash

bench: setup
	$(PY) bench/calibration.py

clean-venv:
	rm -rf $(VENV)
