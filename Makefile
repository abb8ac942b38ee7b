# cellsight: the whole set-up is `make demo` and `make test`.
PY      := .venv/bin/python
STAMP   := .venv/.installed
export MUJOCO_GL ?= egl

.PHONY: venv test demo bench lint clean

venv: $(STAMP)

$(STAMP): pyproject.toml
	test -x $(PY) || python3 -m venv .venv
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[dev]"
	touch $(STAMP)

lint: venv
	.venv/bin/ruff check cellsight tests bench

test: venv lint
	$(PY) -m pytest

demo: venv
	.venv/bin/cellsight show --out out/show
	.venv/bin/cellsight visibility

# Open3D (a benchmark peer) needs libusb; install it from Debian when missing.
bench: venv
	@ldconfig -p | grep -q libusb-1.0 || (apt-get update -qq && apt-get install -y -qq libusb-1.0-0)
	$(PY) bench/run_all.py

clean:
	rm -rf .venv out .pytest_cache .ruff_cache
