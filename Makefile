# The two commands a new user needs: `make demo` and `make test`.
SHELL := /bin/bash
VENV := .venv
PY := $(VENV)/bin/python
DEMO_OUT ?= out/demo

.PHONY: setup demo test lint bench clean-venv

setup:
	@bash tools/setup_env.sh

demo: setup
	$(VENV)/bin/bijcr run scenes/demo --out $(DEMO_OUT)

test: setup
	@bash tools/setup_test_deps.sh
	$(VENV)/bin/ruff check .
	$(PY) -m pytest -q -p no:cacheprovider -p no:dash -n auto --dist loadscope --no-loadscope-reorder

lint: setup
	$(VENV)/bin/ruff check .

# Every bench runs and prints all its rows (FAIL rows included; a bench exits 0 once it ran), and the
# tables are always assembled; a bench that crashed is reported, and fails `make bench` at the end.
bench: setup
	@status=0; for b in calibration estimators reconstruction real segmentation segmentation_steps motion grasping tasks pipeline; do \
	  echo "== bench/$$b.py"; nice $(PY) bench/$$b.py || { echo "== bench/$$b.py did not finish"; status=1; }; \
	done; \
	$(PY) tools/assemble_benchmarks.py; exit $$status

clean-venv:
	rm -rf $(VENV)
