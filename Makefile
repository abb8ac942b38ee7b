# cellsight: the whole set-up is `make demo` and `make test`.
PY      := .venv/bin/python
STAMP   := .venv/.installed
DEV     := .venv/.installed-dev
export MUJOCO_GL ?= egl

.PHONY: venv dev test demo experiments bench fuzz lint clean

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

test: dev lint
	$(PY) -m pytest

# The main job: the paper's third experiment on the built-in cell (report in out/experiment3).
demo: venv
	.venv/bin/cellsight run 3 --out out/experiment3 --overwrite

# The README's table: experiments 1-3 x sensors x seeds, with and without occlusion prediction
# (the comparisons on the first seed), resumable: `cellsight sweep` (out/table/summary.*).
experiments: venv
	.venv/bin/cellsight sweep --out out/table --experiments 1 2 3 --sensors rendered ideal \
		--variants pred nopred prior --seeds 0 1 2 --variant-seeds 1 --jobs 2

# Hostile and random input, 10^5 cases (a few thousand run in `make test`); tests/fuzzing.py.
fuzz: dev
	$(PY) scripts/fuzz.py --out out/fuzz

# Open3D (a benchmark peer) needs libusb; install it from Debian when missing.
bench: dev
	@ldconfig -p | grep -q libusb-1.0 || (apt-get update -qq && apt-get install -y -qq libusb-1.0-0)
	$(PY) bench/run_all.py

clean:
	rm -rf .venv out .pytest_cache .ruff_cache
