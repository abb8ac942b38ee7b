# cellsight: the whole set-up is `make demo` and `make test`.
PY      := .venv/bin/python
STAMP   := .venv/.installed
DEV     := .venv/.installed-dev
export MUJOCO_GL ?= egl

.PHONY: venv dev test test-slow demo experiments results docs recordings bench bench-docs fuzz lint clean

# `venv`: what cellsight needs to run; `dev`: plus the test tools and the benchmark peers.
venv: $(STAMP)
dev: $(DEV)

$(STAMP): pyproject.toml
	test -x $(PY) || python3 -m venv .venv
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e .
	touch $(STAMP)

$(DEV): $(STAMP)
	$(PY) -m pip install --quiet -e ".[dev]"
	touch $(DEV)

lint: dev
	.venv/bin/ruff check cellsight tests bench scripts examples docs/gen

# The suite runs on every core (at most 4; each test module stays on one worker, so its
# fixtures are built once). `make test` leaves out the long end-to-end tests (marked slow),
# which `make test-slow` runs; CI runs both. It prints its 15 slowest tests: keep it under 10 min.
test: dev lint
	$(PY) -m pytest -n auto --maxprocesses 4 --dist loadscope -m "not slow" --durations=15

test-slow: dev
	$(PY) -m pytest -n auto --maxprocesses 4 --dist loadscope -m slow

# The main job: the built-in cell calibrated by its own robots (out/calibration), then the
# paper's third experiment on it, in a world with a lab cell's errors (report in
# out/experiment3).
demo: venv
	.venv/bin/cellsight calibrate --realism lab --seed 0 --out out/calibration --overwrite
	.venv/bin/cellsight run 3 --realism lab --seed 0 --calibration out/calibration --out out/experiment3 --overwrite

# The results pages' sweeps (docs/results/sweeps.yaml: experiments 1-3, rendered, 20 seeds, in
# the `lab` and `harsh` worlds, and the comparisons), resumable: out/<name>/summary.*.
# `make results` then copies the finished ones into docs/results/data/ with the command and the
# version that made them, and writes the README's headline table.
experiments: venv
	$(PY) scripts/publish_results.py run

results: venv
	$(PY) scripts/publish_results.py publish

# The documentation site (MkDocs; build/site/index.html), warnings as errors; the tutorials in
# examples/ run as it builds. (The two variables silence banners of MkDocs' plugins.)
docs: dev
	NO_MKDOCS_2_WARNING=1 DISABLE_MKDOCS_2_WARNING=true .venv/bin/mkdocs build --strict --quiet

# The recording round trip (docs/recording_roundtrip.png): experiment 3 in the lab world recorded lossless and as JPEG,
# each tracked back with `cellsight track`, against the run (docs/recording_roundtrip.png).
REC := .venv/bin/cellsight run 3 --realism lab --seed 0 --quiet --overwrite
recordings: venv
	$(REC) --out out/recordings/run --record out/recordings/lossless.mcap
	$(REC) --out out/recordings/run-jpeg --record out/recordings/jpeg90.mcap --record-jpeg 90
	.venv/bin/cellsight track out/recordings/lossless.mcap --out out/recordings/lossless --quiet --overwrite
	.venv/bin/cellsight track out/recordings/jpeg90.mcap --out out/recordings/jpeg90 --quiet --overwrite
	$(PY) scripts/recording_roundtrip.py out/recordings/run out/recordings/lossless \
		out/recordings/jpeg90 --out docs/recording_roundtrip.png

# Hostile and random input, by default 114,500 cases (about a thousand run in `make test`),
# run folders, recordings and sweep resumes among them; tests/fuzzing.py.
fuzz: dev
	$(PY) scripts/fuzz.py --out out/fuzz

# Open3D (a benchmark peer) needs libusb; install it from Debian when missing.
bench: dev
	@ldconfig -p | grep -q libusb-1.0 || (apt-get update -qq && apt-get install -y -qq libusb-1.0-0)
	$(PY) bench/run_all.py

# The benchmarks' tables saved for the docs' Benchmarks page (run it on a quiet machine).
bench-docs: dev
	@ldconfig -p | grep -q libusb-1.0 || (apt-get update -qq && apt-get install -y -qq libusb-1.0-0)
	$(PY) bench/run_all.py --save docs/results/bench

clean:
	rm -rf .venv out build docs/tutorials .pytest_cache .ruff_cache
