# Two commands on a fresh machine: `make demo` and `make test`. Each creates the virtual
# environment in .venv and installs the package with what it needs.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test view bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/pxr-layers demo -o demo

# The layer inspector on the demo's output (renders it first if it is not there).
view: $(STAMP)
	test -f demo/demo.pxlidx || $(BIN)/pxr-layers demo -o demo
	$(BIN)/pxr-layers view demo

test: $(STAMP)
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	$(BIN)/python benchmarks/bench_render.py
	$(BIN)/python benchmarks/bench_covariance.py
	$(BIN)/python benchmarks/bench_index.py
	$(BIN)/python benchmarks/bench_extract.py
	$(BIN)/python benchmarks/bench_multipart.py
	$(BIN)/python benchmarks/bench_jobs.py
	$(BIN)/python benchmarks/bench_stage.py
	$(BIN)/python benchmarks/bench_suggest.py
	$(BIN)/python benchmarks/bench_cryptomatte.py
	$(BIN)/python benchmarks/bench_view.py || test $$? -eq 2  # 2: no Chromium (the browser benchmark)
	$(BIN)/python benchmarks/bench_looks.py || test $$? -eq 2  # 2: no ../shared (the OpenChessSet)
	$(BIN)/python benchmarks/bench_lights.py
	$(BIN)/python benchmarks/bench_scaling.py
	$(BIN)/python benchmarks/bench_defaults.py
	$(BIN)/python benchmarks/bench_instancing.py
	$(BIN)/python benchmarks/luxtest_table.py || test $$? -eq 2  # 2: no ../shared (the luxtest stages)
	$(BIN)/python benchmarks/bench_vs_mitsuba.py || test $$? -eq 2  # 2: Mitsuba not installed (optional)
	$(BIN)/python benchmarks/bench_vs_mitsuba.py --lens 0.1 1100 || test $$? -eq 2  # depth of field, the same

clean:
	rm -rf $(VENV) demo build *.egg-info
