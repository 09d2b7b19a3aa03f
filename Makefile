# Two entry points for a fresh machine with only Python and pip: `make run` and `make test`.
PY ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test bench lint clean demo-logs

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e '.[test]'
	touch $(STAMP)

run: $(STAMP)
	$(BIN)/frictionwatch analyze replay_logs/demo.mcap

test: $(STAMP)
	$(BIN)/python -m pytest

bench: $(STAMP)
	$(BIN)/python -m bench.run

lint: $(STAMP)
	$(BIN)/ruff check core drivers service tests bench

clean:
	rm -rf $(VENV) .pytest_cache

demo-logs: $(STAMP)
	sed -n '/^```sh/,/^```/p' replay_logs/README.md | grep '^frictionwatch' | while read -r cmd; do $(BIN)/$$cmd || exit 1; done
