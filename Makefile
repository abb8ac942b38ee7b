# cellsight: the whole set-up is `make demo` and `make test`.
PY      := .venv/bin/python
STAMP   := .venv/.installed
DEV     := .venv/.installed-dev
export MUJOCO_GL ?= egl

.PHONY: venv dev test demo experiments recordings bench fuzz lint clean

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
	.venv/bin/ruff check cellsight tests bench scripts

# The suite runs on every core (at most 4; each test module stays on one worker, so its
# fixtures are built once).
test: dev lint
	$(PY) -m pytest -n auto --maxprocesses 4 --dist loadscope

# The main job: the paper's third experiment on the built-in cell, in a world with a well
# calibrated lab cell's errors (report in out/experiment3).
demo: venv
	.venv/bin/cellsight run 3 --realism lab --out out/experiment3 --overwrite

# The README's tables, resumable (`cellsight sweep`; out/<table>/summary.*): experiments 1-3,
# rendered, 20 seeds, occlusion prediction on and off paired on the same seeds, in the `lab`
# world and in the `harsh` world; `lab` without its cameras' errors, 20 seeds; camera offsets
# estimated in `harsh` and with `harsh`'s cameras alone, and in `exact` and `lab`, paired with
# the plain tracker; the paper's per-frame BSP against the per-object hierarchies, experiment 3,
# 20 seeds (the later --experiments wins); the fault table: each knob group of
# `harsh` alone, 5 seeds, prediction on and off; the kinematic prior (the held part, the part
# on its support, the cameras registered to the gripper) in `harsh`, 20 seeds, paired with the
# plain tracker.
SEEDS20 := 0 1 2 3 4 5 6 7 8 9 10 11 12 13 14 15 16 17 18 19
SWEEP   := .venv/bin/cellsight sweep --experiments 1 2 3 --sensors rendered --jobs 2
experiments: venv
	$(SWEEP) --out out/lab --realism lab --variants pred nopred --seeds $(SEEDS20)
	$(SWEEP) --out out/harsh --realism harsh --variants pred nopred --seeds $(SEEDS20)
	$(SWEEP) --out out/lab-nocam --realism lab/robots+servo+geometry+images+timing+scenario \
		--variants pred --seeds $(SEEDS20)
	$(SWEEP) --out out/offsets --realism harsh/cameras harsh --variants offsets pred \
		--seeds 0 1 2 3 4
	$(SWEEP) --out out/offsets-lab --realism exact lab --variants offsets pred --seeds 0 1
	$(SWEEP) --out out/lab-offsets --realism lab --variants offsets pred --seeds $(SEEDS20)
	$(SWEEP) --out out/structures --realism lab --structure object-bvh frame-bsp \
		--experiments 3 --seeds $(SEEDS20)
	$(SWEEP) --out out/faults --seeds 0 1 2 3 4 --variants pred nopred \
		--realism harsh/cameras harsh/robots harsh/servo harsh/geometry harsh/unmodelled \
		harsh/images harsh/timing harsh/scenario
	$(SWEEP) --out out/harsh-hold --realism harsh --variants prior pred --seeds $(SEEDS20)

# The README's recording table: experiment 3 in the lab world recorded lossless and as JPEG,
# each tracked back with `cellsight track`, against the run (docs/recording_roundtrip.png).
REC := .venv/bin/cellsight run 3 --realism lab --seed 0 --quiet --overwrite
recordings: venv
	$(REC) --out out/recordings/run --record out/recordings/lossless.mcap
	$(REC) --out out/recordings/run-jpeg --record out/recordings/jpeg90.mcap --record-jpeg 90
	.venv/bin/cellsight track out/recordings/lossless.mcap --out out/recordings/lossless --quiet --overwrite
	.venv/bin/cellsight track out/recordings/jpeg90.mcap --out out/recordings/jpeg90 --quiet --overwrite
	$(PY) scripts/recording_roundtrip.py out/recordings/run out/recordings/lossless \
		out/recordings/jpeg90 --out docs/recording_roundtrip.png

# Hostile and random input, 10^5 cases (about a thousand run in `make test`); tests/fuzzing.py.
fuzz: dev
	$(PY) scripts/fuzz.py --out out/fuzz

# Open3D (a benchmark peer) needs libusb; install it from Debian when missing.
bench: dev
	@ldconfig -p | grep -q libusb-1.0 || (apt-get update -qq && apt-get install -y -qq libusb-1.0-0)
	$(PY) bench/run_all.py

clean:
	rm -rf .venv out .pytest_cache .ruff_cache
