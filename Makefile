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
	@bash tools/setup_test_deps.sh
	$(PY) -m pytest -q -p no:cacheprovider -p no:dash

bench: setup
	@for b in calibration reconstruction segmentation motion grasping tasks; do \
	  echo "== bench/$$b.py"; nice $(PY) bench/$$b.py || exit 1; done
	$(PY) tools/assemble_benchmarks.py

clean-venv:
	rm -rf $(VENV)
