# Two commands on a fresh machine: `make demo` and `make test`. Each bootstraps .venv itself.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
OUT    ?= demo-out
JOBS   ?= 2
# e.g. DEMO_FLAGS='--full-view --keep-data': the view at full rate, the recordings and estimates
DEMO_FLAGS ?=

.PHONY: setup demo test study bench fuzz lint lock clean docs validation

$(STAMP): pyproject.toml requirements.lock
	$(PYTHON) -c 'import sys; assert sys.version_info >= (3, 11), "ditherlab needs Python >= 3.11"'
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -c requirements.lock -e '.[dev,docs]'
	touch $(STAMP)

setup: $(STAMP)

demo: $(STAMP)
	$(PY) -m ditherlab.app.demo --out $(OUT) $(DEMO_FLAGS)

test: $(STAMP)
	$(PY) -m pytest -q -n $(JOBS) --dist loadfile -m "not study"

# The study tier: the properties of make test over every planted effect, seed and cut point.
study: $(STAMP)
	$(PY) -m pytest -q -n $(JOBS) --dist loadfile -m study

# The documentation site (mkdocs-material, API from the docstrings, notebooks rendered) into
# site/: the generated pages first (the effect library, the command line), then a strict build.
docs: $(STAMP)
	$(PY) scripts/effects_page.py
	$(PY) scripts/cli_page.py
	$(VENV)/bin/mkdocs build --strict

# The measured evidence of docs/validation.md (and .json), written by the script from runs: the
# paper's table over SEEDS seeds, false discoveries on clean recordings, the real-log loop, the
# bench's ratios, the fuzz campaign. About an hour or more on 2 cores; --quick for a smoke run.
SEEDS  ?= 7
PUSHES ?= 25
validation: $(STAMP)
	$(PY) scripts/validation.py --seeds $(SEEDS) --pushes $(PUSHES) --jobs $(JOBS) --out docs/validation.md

bench: $(STAMP)
	$(PY) -m bench.run

# The fuzz campaign (tests/fuzz): FUZZ_CASES cases over every command and input kind, one process
# each, reproducible from FUZZ_SEED; findings with reproductions in fuzz-findings.md. `make test`
# runs a small budget of it (tests/test_fuzz.py).
FUZZ_CASES ?= 1000
FUZZ_SEED  ?= 1
fuzz: $(STAMP)
	$(PY) -m tests.fuzz --cases $(FUZZ_CASES) --seed $(FUZZ_SEED) --work /tmp/ditherlab-fuzz \
		--findings fuzz-findings.md

lint: $(STAMP)
	$(VENV)/bin/ruff check ditherlab tests bench
	$(VENV)/bin/ruff format --check ditherlab tests bench

# Re-pin after changing dependencies in pyproject.toml.
lock: $(STAMP)
	$(PY) -m pip freeze --exclude-editable | grep -v '^-e' > requirements.lock

clean:
	rm -rf $(VENV) $(OUT) site .pytest_cache .ruff_cache
