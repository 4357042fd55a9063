# depthmocap: the two commands a newcomer needs are `make demo` (sets up, then runs the main
# job on a built-in synthetic sequence) and `make test`. Everything runs from the repo's .venv.
PY := .venv/bin/python
SETUP_STAMP := .venv/.setup-stamp
export PYTHONUNBUFFERED := 1

.PHONY: setup demo test lint format bench bench-broad install-check clean synth dev-recordings dev-recordings-all dev-protocol dev-protocol-eval train-forest train-forest-eval \
	synth-calib train-forest-calib synth-clutter train-clutter pose-prior

setup: ## create .venv, install system packages (root), torch and the project with all extras
	@bash scripts/setup.sh

$(SETUP_STAMP): pyproject.toml setup.py scripts/setup.sh
	@bash scripts/setup.sh

DEMO := out/demo
demo: $(SETUP_STAMP) ## set up if needed; render a person, personalize their body, track, evaluate
	$(PY) -m depthmocap.train.synth.cli --sequence --motion wave --frames 120 --seed 1 --overwrite \
		--quiet --out $(DEMO)/recording
	$(PY) -m depthmocap.train.synth.calibration_views --out $(DEMO)/views --phenotype-from $(DEMO)/recording \
		--seed 7 --overwrite
	$(PY) -m depthmocap.runtime.personalize_cli --input $(DEMO)/views --output $(DEMO)/body.json
	$(PY) -m depthmocap.runtime.track_cli --input $(DEMO)/recording --output $(DEMO)/result \
		--mode hybrid --config configs/hybrid.yaml --body $(DEMO)/body.json --save-overlays
	$(PY) -m depthmocap.train.evaluation.cli --recording $(DEMO)/recording --result $(DEMO)/result \
		--json $(DEMO)/metrics.json
	@echo "demo outputs: $(DEMO)/result (poses.jsonl, motion.bvh, summary.json, overlays/),"
	@echo "  metrics $(DEMO)/metrics.json, plot $(DEMO)/result/evaluation.png"

test: $(SETUP_STAMP) ## lint, then the whole test suite
	$(PY) -m ruff check .
	$(PY) -m pytest -q --durations=15

lint: $(SETUP_STAMP)
	$(PY) -m ruff check .
	$(PY) -m ruff format --check .

format: $(SETUP_STAMP)
	$(PY) -m ruff format .
	$(PY) -m ruff check --fix .

synth: $(SETUP_STAMP) ## the ~20k-frame training set into data/synth (resumable)
	$(PY) -m depthmocap.train.synth.cli --config configs/synth.yaml --out data/synth

dev-recordings: $(SETUP_STAMP) ## evaluation recordings from the HDM05 dev clips into data/dev
	$(PY) -m depthmocap.train.evaluation.dev_recordings --out data/dev

dev-recordings-all: $(SETUP_STAMP) ## every tracked dev take (39 clips, 2,433 frames) into data/dev_all, data/dev_all_calib
	$(PY) -m depthmocap.train.evaluation.dev_recordings --all-clips --out data/dev_all

dev-protocol: $(SETUP_STAMP) ## the frozen broad dev protocol (docs/protocol.md) into data/dev_broad, data/dev_broad_calib
	$(PY) -m depthmocap.train.evaluation.dev_recordings --protocol broad --out data/dev_broad

dev-protocol-eval: $(SETUP_STAMP) ## the fully automatic system (hybrid, default body) on data/dev_broad, per class too
	$(PY) -m depthmocap.train.evaluation.dev_benchmark --protocol broad

train-forest: $(SETUP_STAMP) ## the body-part forest from data/synth into models/forest.npz
	$(PY) -m depthmocap.train.forest.train_cli --data data/synth --out models/forest.npz --config configs/forest.yaml

pose-prior: $(SETUP_STAMP) ## the tracker's learned pose prior from the training split's mocap into models/pose_prior.json
	$(PY) -m depthmocap.train.mocap.pose_prior_fit --out models/pose_prior.json

synth-calib: $(SETUP_STAMP) ## the calibration-pose training set (T-pose only) into data/synth_calib
	$(PY) -m depthmocap.train.synth.cli --config configs/synth_calib.yaml --out data/synth_calib

train-forest-calib: $(SETUP_STAMP) ## the calibration forest from data/synth_calib into models/
	$(PY) -m depthmocap.train.forest.train_cli --data data/synth_calib --out models/forest_calib.npz \
		--config configs/forest_calib.yaml

synth-clutter: $(SETUP_STAMP) ## the person/clutter training set (furniture against people) into data/synth_clutter, and a held-out 500 frames
	$(PY) -m depthmocap.train.synth.cli --config configs/synth_clutter.yaml --out data/synth_clutter
	$(PY) -m depthmocap.train.synth.cli --config configs/synth_clutter.yaml --frames 500 --seed 6 \
		--out data/synth_clutter_eval

train-clutter: $(SETUP_STAMP) ## the person/clutter forest from data/synth_clutter into models/clutter_forest.npz
	$(PY) -m depthmocap.train.forest.train_cli --data data/synth_clutter --out models/clutter_forest.npz \
		--config configs/forest_clutter.yaml --eval-data data/synth_clutter_eval

train-forest-eval: $(SETUP_STAMP) ## accuracy of models/forest.npz on the dev recordings
	$(PY) -m depthmocap.train.forest.eval_cli --model models/forest.npz --data data/dev --out out/forest_eval

bench: $(SETUP_STAMP) ## speed figures (CPU, and CUDA when torch sees a GPU), then the accuracy table on data/dev (printed, never asserted)
	$(PY) -m depthmocap.bench --device all $(if $(wildcard data/dev),--recordings data/dev --hybrid-recordings data/dev,)
	@if [ -d data/dev ]; then $(PY) -m depthmocap.train.evaluation.dev_benchmark --recordings data/dev; \
	else echo "accuracy table skipped: no data/dev (run make dev-recordings)"; fi

bench-broad: $(SETUP_STAMP) ## the whole hybrid's speed over the broad protocol's 116 recordings (data/dev_broad; ~12 min)
	$(PY) -m depthmocap.bench --hybrid-frames 0 --hybrid-recordings data/dev_broad

install-check: $(SETUP_STAMP) ## install the checkout into a fresh venv outside it and track the demo from elsewhere
	$(PY) -m pytest -q tests/test_install.py

clean:
	rm -rf .venv .pytest_cache .ruff_cache
