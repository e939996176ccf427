# The two commands of the README:
#   make fit    set up everything, generate the synthetic session, fit it end to end (with held-out
#               checks), write the report, and check the fit against the session's ground truth
#   make test   set up everything, run every test (Rust core without Python, then Python)
# and, for maintainers, the table the package ships:
#   make table-italian   regenerate python/coartic/runtime/italian_table.json (and its provenance)
#   make table-italian-changed   the same, refitting only the lip and jaw channels whose data changed
PY := .venv/bin/python
UV := .venv/bin/uv
.PHONY: setup fit fit-emotive test test-rust test-python test-python-core-wheel test-core core-wheel core-tests stubtest typecheck bench clean wheel table-italian table-italian-changed

setup:
	./scripts/setup.sh

# A rerun refits and replaces results/synthetic whole (its own output: no --force; docs/OUTPUTS.md).
fit: setup
	[ -f build/session/manifest.csv ] || $(PY) -m coartic.cli corpus synth build/session
	$(PY) -m coartic.cli fit fit/synthetic.toml --out results/synthetic --validate
	$(PY) fit/check_recovery.py results/synthetic

# The emotive flavour (corpus-synthetic/emotions.toml: /a i u/ x /p b m f v t/, neutral and Ekman's six
# emotions, 504 trials) fitted with emotion as a factor (fit/emotive.toml, docs/EMOTIONS.md), then
# every emotion's deviation from the neutral targets checked against the truth (fit/check_emotions.py).
fit-emotive: setup
	[ -f build/emotive/manifest.csv ] || $(PY) -m coartic.cli corpus synth build/emotive --flavour emotive
	$(PY) -m coartic.cli fit fit/emotive.toml --out results/emotive --validate
	$(PY) fit/check_emotions.py results/emotive build/emotive/ground_truth.json

# The Italian flavour of the synthetic session (every Italian phoneme): its lip and jaw channels
# (face markers, fit/italian.toml) and its tongue channels (EMA files, fit/italian_tongue.toml) fitted
# with held-out checks, checked for recovery, then shipped as one table with its provenance
# (fit/ship_table.py). About an hour and a quarter on a busy 2-core machine; the result is committed, so
# only a change of ground_truth_italian.json, session.toml or the two specs calls for it (a test says so).
table-italian: setup
	$(PY) -m coartic.cli corpus synth build/italian --flavour italian
	$(PY) -m coartic.cli fit fit/italian.toml --out results/italian --validate
	$(PY) -m coartic.cli fit fit/italian_tongue.toml --out results/italian_tongue --validate
	$(PY) fit/ship_table.py --lips results/italian --tongue results/italian_tongue --session build/italian

# The same, refitting only the lip and jaw channels whose data changed: fit/changed_channels.py
# regenerates the session the shipped table was fitted on (from the commit whose inputs its
# provenance records) and compares every trial's channels bit for bit; the model is per channel, so
# the others are kept from the shipped table (the provenance says which). The tongue is refitted.
table-italian-changed: setup
	$(PY) -m coartic.cli corpus synth build/italian --flavour italian
	$(PY) fit/changed_channels.py --session build/italian --previous build/italian-previous
	changed=$$($(PY) -c 'import json; print(",".join(json.load(open("build/italian/changed_channels.json"))["changed"]))'); \
	if [ -n "$$changed" ]; then \
	  $(PY) -m coartic.cli fit fit/italian.toml --out results/italian --validate --channels "$$changed"; \
	else echo "no lip or jaw channel changed: nothing to refit there" >&2; exit 1; fi
	$(PY) -m coartic.cli fit fit/italian_tongue.toml --out results/italian_tongue --validate
	$(PY) fit/ship_table.py --lips results/italian --tongue results/italian_tongue --session build/italian --keep-unchanged

# The core wheel (build/core-wheel) is built first: core-tests installs it, and test-python's wheel
# test installs the same wheel. Then the five parts run side by side (-j3, each part's output printed
# whole when it ends, every part run and any failure failing make test), the longest first: mypy,
# stubtest and the core environment's install and tests use one core each, and one after the other they
# left the second core idle while the Python tests waited (bench/results/test_suite_cpu.txt).
test: setup core-wheel
	$(MAKE) -j3 --output-sync=target --keep-going test-python-core-wheel typecheck test-rust core-tests stubtest

# make test's Python session: the wheel test installs core-wheel's wheel, and the core files' tests that
# core-tests runs on that wheel are left to it (tests/python/conftest.py, COARTIC_CORE_TESTS): they ran twice
test-python-core-wheel:
	COARTIC_WHEEL_DIR=$(CURDIR)/build/core-wheel COARTIC_CORE_TESTS="$(CORE_TESTS)" $(MAKE) test-python

# dist/coartic-VERSION-cp311-abi3-PLATFORM.whl: one wheel for every CPython >= 3.11 (pyo3's
# abi3-py311), installed by pip without Rust (tests/python/test_wheel.py). Reuses make setup's build.
wheel: setup
	$(PY) -m maturin build --release -o dist

# `pip install coartic` without extras, as a new user gets it: the wheel of this checkout in a fresh
# environment, its core dependencies from the package index, then the tests the core must pass
# (the extras' commands must name their extra: tests/python/test_extras.py), test_extras.py last: its
# last test installs an extra over the core (COARTIC_WHEEL), after every test that needs the core alone.
CORE_TESTS := tests/python/test_io_formats.py tests/python/test_io_carstens.py tests/python/test_core_model.py \
	tests/python/test_table.py tests/python/test_extras.py
test-core: core-wheel
	$(MAKE) core-tests

core-wheel: setup
	rm -rf build/core-wheel
	$(PY) -m maturin build --release --quiet -o build/core-wheel

# the tests of test-core on the wheel core-wheel built. The environment is made for this run and
# thrown away: uv (make setup's, one of the dev tools) installs pip (the on-demand extra's test runs it),
# the wheel, its core dependencies and the test tools into it from the package index, keeping the wheels
# it downloads in its cache (~/.cache/uv; pip's HTTP cache kept nothing here, the index sending no caching
# headers), and compiles nothing: the tests' Python writes the bytecode of the modules they import, once
# for every test process after it (PYTHONDONTWRITEBYTECODE= even where the caller set it). The install
# cost 11 CPU-s with pip, 2.1 with uv on an empty cache, 0.6 on a warm one; the target 50 -> 34 CPU-s
# side by side under load (bench/results/test_suite_cpu_core3.txt).
core-tests:
	rm -rf build/core-env
	python3 -m venv --without-pip build/core-env
	$(UV) pip install -q --python build/core-env/bin/python pip build/core-wheel/coartic-*.whl pytest hypothesis
	cd build && PYTHONDONTWRITEBYTECODE= COARTIC_CORE_ONLY=1 COARTIC_WHEEL=$$(ls $$PWD/core-wheel/coartic-*.whl) \
	  core-env/bin/python -m pytest -q -p no:cacheprovider $(addprefix ../,$(CORE_TESTS))

test-rust:
	cargo test --profile release-tests --quiet

stubtest:
	$(PY) -m mypy.stubtest coartic._core --allowlist tests/stubtest-allowlist.txt --mypy-config-file tests/stubtest-mypy.ini

typecheck:
	$(PY) -m mypy

# Bytecode is written (PYTHONDONTWRITEBYTECODE= even where the caller set it): pytest's rewritten test modules,
# made once by the xdist controller for both workers (conftest.py) and kept for the next run, and the
# checkout's modules, compiled once for the many coartic commands the tests start.
test-python:
	PYTHONDONTWRITEBYTECODE= $(PY) -m pytest -q -n 2 --dist loadfile tests/python

# Each benchmark prints ratios measured in one run and saves its output in bench/results/.
bench: setup
	$(PY) bench/core_speed.py
	$(PY) bench/fit_speed.py
	$(PY) bench/mcmc_speed.py
	$(PY) bench/mcmc_moves.py
	$(PY) bench/runtime_contacts.py
	$(PY) bench/runtime_speed.py
	$(PY) bench/batch_scaling.py

clean:
	rm -rf target .venv results build
