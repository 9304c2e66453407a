# Two commands matter: `make demo` and `make test`. Both set everything up on a fresh machine.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test test-slow setup browser postgres assets lint bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --disable-pip-version-check --upgrade pip
	$(BIN)/python -m pip install --quiet --disable-pip-version-check -e '.[dev]'
	touch $(STAMP)

setup: $(STAMP) browser postgres

# Debian packages some tests need, installed when missing and `make` runs as root; elsewhere a
# note says which test will be skipped. $(1): a shell test true when the package is there,
# $(2): the package, $(3): the test that needs it.
define debian_package
	@if $(1); then \
		:; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
		echo "installing Debian's $(2) for $(3):"; \
		echo "apt-get update && apt-get install -y --no-install-recommends $(2)"; \
		apt-get update -qq && apt-get install -y -qq --no-install-recommends $(2); \
	else \
		echo "note: no $(2), so $(3) will be skipped;"; \
		echo "as root: apt-get install --no-install-recommends $(2)"; \
	fi
endef

# The dashboard's browser tests drive Debian's chromium, never a browser downloaded by Playwright.
browser:
	$(call debian_package,[ -x /usr/bin/chromium ],chromium,the dashboard's browser test)

# The PostgreSQL test (tests/test_postgres.py) runs Debian's server in a temporary cluster.
postgres:
	$(call debian_package,ls /usr/lib/postgresql/*/bin/pg_ctl >/dev/null 2>&1,postgresql,the PostgreSQL test)

assets: $(STAMP)
	$(BIN)/ringside assets pull

demo: $(STAMP)
	$(BIN)/ringside demo

# Two processes, as CI's two cores: most tests wait on a server or a subprocess part of the
# time. A file's tests stay on one process, in order, with their fixtures. The 30 slowest are
# listed at the end, for keeping the suite inside its 20 minutes on CI.
test: $(STAMP) browser postgres lint
	$(BIN)/ringside assets pull --dev
	$(BIN)/python -m pytest -n 2 --dist loadfile --durations=30

# The tests too long for `make test` and CI: SIGKILL at 20 random moments of a pipeline run
# (tests/test_kills.py), two pipeline workers (tests/test_workers.py) and a run killed on a
# DuckLake catalog (tests/test_lake_workers.py).
test-slow: $(STAMP) postgres
	$(BIN)/ringside assets pull --dev
	$(BIN)/python -m pytest -m slow -s

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

# These measure what the user names (an opponent folder, a training run): their docstrings say how.
BENCH_INPUTS := benchmarks/matched_assist.py benchmarks/matched_falls.py benchmarks/matched_trace.py benchmarks/replay_telltales.py

bench: assets
	@for script in benchmarks/[!_]*.py; do \
	  case " $(BENCH_INPUTS) " in *" $$script "*) echo "== $$script: left out, it needs an input (see its docstring)"; continue;; esac; \
	  echo "== $$script"; $(BIN)/python $$script || exit 1; \
	done

clean:
	rm -rf $(VENV) data
