# Two commands matter: `make demo` and `make test`. Both set everything up on a fresh machine.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test test-kills setup browser postgres assets lint bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --disable-pip-version-check --upgrade pip
	$(BIN)/python -m pip install --quiet --disable-pip-version-check -e '.[dev]'
	touch $(STAMP)

setup: $(STAMP) browser postgres

# The dashboard's browser tests drive Debian's chromium, never a browser downloaded by Playwright.
browser:
	@if [ -x /usr/bin/chromium ]; then \
		:; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
		echo "installing Debian's chromium for the dashboard's browser tests:"; \
		echo "apt-get update && apt-get install -y --no-install-recommends chromium"; \
		apt-get update -qq && apt-get install -y -qq --no-install-recommends chromium; \
	else \
		echo "note: no /usr/bin/chromium, so the dashboard's browser test will be skipped;"; \
		echo "as root: apt-get install --no-install-recommends chromium"; \
	fi

# The PostgreSQL test (tests/test_postgres.py) runs Debian's server in a temporary cluster.
postgres:
	@if ls /usr/lib/postgresql/*/bin/pg_ctl >/dev/null 2>&1; then \
		:; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
		echo "installing Debian's PostgreSQL server for the PostgreSQL test:"; \
		echo "apt-get update && apt-get install -y --no-install-recommends postgresql"; \
		apt-get update -qq && apt-get install -y -qq --no-install-recommends postgresql; \
	else \
		echo "note: no PostgreSQL server, so the PostgreSQL test will be skipped;"; \
		echo "as root: apt-get install --no-install-recommends postgresql"; \
	fi

assets: $(STAMP)
	$(BIN)/ringside assets pull

demo: $(STAMP)
	$(BIN)/ringside demo

test: $(STAMP) browser postgres lint
	$(BIN)/ringside assets pull --dev
	$(BIN)/python -m pytest

# SIGKILL at 20 random moments of a pipeline run (tests/test_kills.py, about 20 minutes).
test-kills: $(STAMP)
	$(BIN)/ringside assets pull --dev
	$(BIN)/python -m pytest -m slow -s tests/test_kills.py

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

bench: assets
	@for script in benchmarks/[!_]*.py; do echo "== $$script"; $(BIN)/python $$script || exit 1; done

clean:
	rm -rf $(VENV) data
