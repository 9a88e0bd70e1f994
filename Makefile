# Every target bootstraps .venv itself: torch's CPU wheel first, then the project (editable).
PY      := .venv/bin/python
STAMP   := .venv/.installed
TORCH   := torch==2.13.0

.PHONY: demo test test-all bench report lint clean model model-int8 flow-model

$(STAMP): pyproject.toml
	test -x $(PY) || python3 -m venv .venv
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet $(TORCH)
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	.venv/bin/supportnet demo --out demo_out --overwrite

test: $(STAMP)
	.venv/bin/ruff check calib supportnet train export tests benchmarks
	$(PY) -m pytest -q

test-all: $(STAMP)
	$(PY) -m pytest -q -m ''

# Speed and accuracy benchmarks: JSON and RESULTS.md under benchmarks/results/, nothing else.
bench: $(STAMP)
	$(PY) benchmarks/bench_synth.py
	$(PY) benchmarks/bench_matcher.py
	$(PY) benchmarks/bench_refine.py
	$(PY) benchmarks/bench_speed.py
	$(PY) benchmarks/bench_predictor.py
	$(PY) benchmarks/bench_hand_eye.py
	$(PY) benchmarks/bench_flow_matcher.py
	$(PY) benchmarks/bench_accuracy.py
	$(PY) benchmarks/bench_check.py
	$(PY) benchmarks/bench_realism.py
	$(PY) benchmarks/bench_real.py
	$(PY) benchmarks/bench_stage1.py
	$(PY) benchmarks/report.py

# The README's results tables, from what `make bench` left in benchmarks/results/ (bench never
# touches README.md).
report: $(STAMP)
	$(PY) benchmarks/report.py --readme README.md

lint: $(STAMP)
	.venv/bin/ruff check calib supportnet train export tests benchmarks
	.venv/bin/ruff format --check calib supportnet train export tests benchmarks

clean:
	rm -rf .venv demo_out .pytest_cache

# The shipped support predictor (supportnet/assets/support_unet.onnx and its model card), re-made
# with fixed seeds: synthetic data and maps under build/model, then train, export, quantise to 8
# bits (support_unet_int8.onnx, what --support onnx runs) and score both.
model: $(STAMP)
	$(PY) -m train.recipe support

# The 8-bit predictor alone, from the shipped float one (its data re-made under build/model).
model-int8: $(STAMP)
	$(PY) -m train.recipe support-int8

# The shipped flow matcher (supportnet/assets/flow_matcher.onnx and its card), from the same data.
flow-model: $(STAMP)
	$(PY) -m train.recipe flow
