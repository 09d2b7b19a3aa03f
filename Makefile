# Two entry points for a fresh machine with only Python and pip: `make run` and `make test`.
PY ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test bench lint clean clean-numba demo-logs

# setuptools' "Editable installation ... careful with folders of the same name" note comes with every editable
# install (ours maps core/, drivers/, service/ under frictionwatch.*, so no folder shadows the package): filtered;
# every other build warning still shows. A pip configuration whose extra index lacks a package prints one "Location
# ... is ignored" line per package (108 on a machine whose index is a partial local mirror): kept in .venv/pip.log,
# dropped from the terminal; a failed install prints its whole log. --no-compile: pip byte-compiles every installed
# module (dask, pandas, scipy, matplotlib ...) up front, 63 s of CPU against 25 s without (session 33, one pair, load
# ~5); Python compiles the ones a run imports when it first imports them
PIP_NOTICE := is ignored: it is neither a file nor a directory
$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	@echo "installing frictionwatch and its dependencies into $(VENV) (first run only; pip's log: $(VENV)/pip.log)"
	@{ $(BIN)/pip install -q --upgrade pip && PYTHONWARNINGS='ignore:Editable installation' \
	    $(BIN)/pip install -q --no-compile -e '.[test]'; } > $(VENV)/pip.log 2>&1 || { cat $(VENV)/pip.log; exit 1; }
	@grep -v -e '$(PIP_NOTICE)' $(VENV)/pip.log || true
	touch $(STAMP)

# serve the demo log in a loop at real time; it prints the dashboard URL (Ctrl-C stops it)
run: $(STAMP)
	$(BIN)/frictionwatch serve --source 'mcap:replay_logs/demo.mcap?loop=1&speed=1'

# two workers (the CI machine has 2 cores); a test file stays on one worker, so its module fixtures run once; the
# files in tests/conftest.py's order, slow ones first (xdist's default re-sorts them by their number of tests, which
# put 6-test files of 60-140 s late: --no-loadscope-reorder keeps ours); one BLAS thread each, as serve runs (two
# workers' OpenBLAS threads spinning on two cores doubled the suite's time); the 25 slowest tests listed at its end,
# so each CI log says where the suite's time goes (it must stay under 15 minutes)
test: $(STAMP)
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 $(BIN)/python -m pytest -n 2 --dist loadfile \
		--no-loadscope-reorder --durations=25

bench: $(STAMP)
	$(BIN)/python -m bench.run

lint: $(STAMP)
	$(BIN)/ruff check core drivers service tests bench

clean: clean-numba
	rm -rf $(VENV) .pytest_cache

# numba's compiled kernels: one folder per version of core/ and drivers/ (core/numba_cache.py), under
# $NUMBA_CACHE_DIR or ~/.cache/frictionwatch/numba; this removes every version's, and any left beside the sources
clean-numba:
	[ -z "$$NUMBA_CACHE_DIR" ] || rm -rf "$$NUMBA_CACHE_DIR"/frictionwatch-*
	rm -rf "$${XDG_CACHE_HOME:-$$HOME/.cache}/frictionwatch/numba"
	find core drivers service bench tests -name '*.nbi' -delete -o -name '*.nbc' -delete

demo-logs: $(STAMP)
	sed -n '/^```sh/,/^```/p' replay_logs/README.md | grep '^frictionwatch' | while read -r cmd; do $(BIN)/$$cmd || exit 1; done
