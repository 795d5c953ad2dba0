# Two commands on a fresh machine (Python 3.11, gcc, make): `make demo`, `make test`.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-$(shell cksum < pyproject.toml | cut -d' ' -f1)

.PHONY: demo test test-fast bench generate clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check -e '.[test]'
	rm -f $(VENV)/.installed-*
	touch $@

demo: $(STAMP)  ## declare WingRock, generate C, compile, filter simulated data, print the table, write plots
	$(PY) examples/demo.py --out out/demo

test: $(STAMP)  ## the whole suite, one test file per worker process (pytest-xdist)
	$(PY) -m pytest -n auto --dist loadfile

test-fast: $(STAMP)
	$(PY) -m pytest -m "not slow"

bench: $(STAMP)  ## accuracy and speed tables (figures land in benchmarks/figures)
	$(PY) -m skigen bench wingrock
	$(PY) -m skigen bench wingrock --reference staircase
	$(PY) -m skigen bench delay
	$(PY) -m skigen bench quadrotor
	$(PY) -m skigen bench mukf
	$(PY) -m skigen bench speed
	$(PY) -m skigen bench footprint
	$(PY) -m skigen bench diagnose
	$(PY) -m skigen bench false_alarms
	$(PY) -m skigen bench fit
	$(PY) -m skigen bench logs
	$(PY) -m skigen bench batch
	$(PY) -m skigen bench faults

generate: $(STAMP)  ## regenerate the checked-in C sources in generated/
	$(PY) -m skigen.emit.shipped generated

clean:
	rm -rf $(VENV) out build *.egg-info
