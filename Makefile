# Two commands set everything up: `make demo` and `make test`. Each builds the project-local
# environment in .venv from requirements.lock the first time, and only checks a stamp after that.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
PACKAGES := common maps vehicle controller services
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.vrsim-installed

CHROMIUM := /usr/bin/chromium

.PHONY: demo test test-unit test-integration test-accuracy lint bench bytecode clean chromium

$(STAMP): requirements.lock pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --disable-pip-version-check -r requirements.lock
	$(BIN)/python -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation -e .
	$(MAKE) --no-print-directory bytecode
	touch $(STAMP)

# vrsim's own modules compiled once, as pip compiles an installed package's: where the environment
# sets PYTHONDONTWRITEBYTECODE, every process of every run would compile them again (a tenth of a
# second of CPU in `vrsim run`). Python checks each file's source against its bytecode, so a stale
# file is only compiled again, never run.
bytecode:
	$(BIN)/python -m compileall -q $(PACKAGES)

demo: $(STAMP)
	$(BIN)/vrsim run

lint: $(STAMP)
	$(BIN)/ruff check .

test: lint chromium
	$(BIN)/python -m pytest

test-unit: $(STAMP)
	$(BIN)/python -m pytest -m unit

test-integration: $(STAMP) chromium
	$(BIN)/python -m pytest -m integration

# The web page's test drives Debian's Chromium (through Playwright, which downloads no browser):
# install it when it is missing (needs root, as on CI).
chromium:
	@test -x $(CHROMIUM) || { echo "installing Chromium for the web page's test (apt-get, needs root)"; \
		apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium; }

test-accuracy: $(STAMP)
	$(BIN)/python -m pytest -m accuracy

bench: $(STAMP) bytecode
	$(BIN)/python bench/run_all.py

clean:
	rm -rf $(VENV) runs .pytest_cache .ruff_cache
