# depthmocap: the two commands a newcomer needs are `make demo` (once the runtime lands:
# set up, then run the main job) and `make test`. Everything runs from the repo's .venv.
PY := .venv/bin/python
SETUP_STAMP := .venv/.setup-stamp
export PYTHONUNBUFFERED := 1

.PHONY: setup test lint format bench clean synth dev-recordings

setup: ## create .venv, install system packages (root), torch and the project with all extras
	@bash scripts/setup.sh

$(SETUP_STAMP): pyproject.toml scripts/setup.sh
	@bash scripts/setup.sh

test: $(SETUP_STAMP) ## lint, then the whole test suite
	$(PY) -m ruff check .
	$(PY) -m pytest -q

lint: $(SETUP_STAMP)
	$(PY) -m ruff check .
	$(PY) -m ruff format --check .

format: $(SETUP_STAMP)
	$(PY) -m ruff format .
	$(PY) -m ruff check --fix .

synth: $(SETUP_STAMP) ## the ~20k-frame training set into data/synth (resumable)
	$(PY) -m train.synth_cli --config configs/synth.yaml --out data/synth

dev-recordings: $(SETUP_STAMP) ## evaluation recordings from the HDM05 dev clips into data/dev
	$(PY) -m train.dev_recordings --out data/dev

bench: $(SETUP_STAMP) ## speed figures (printed, never asserted)
	$(PY) -m runtime.bench

clean:
	rm -rf .venv .pytest_cache .ruff_cache
