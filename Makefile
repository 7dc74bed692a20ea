# glossdepth: the two commands a newcomer needs are `make demo` and `make test`.
# Both create/update the virtual environment in .venv and install the Debian packages they need.

SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-stamp
# Outputs (renders, sessions, reports) go here; git ignores it.
OUT ?= out
# PsychoPy writes preferences into $HOME: keep them inside the project.
PROJECT_HOME := $(CURDIR)/.home

# Mitsuba's LLVM variants need LLVM >= 17 (libLLVM 15/16 abort at dr.maximum); Debian ships 19.
export DRJIT_LIBLLVM_PATH ?= /usr/lib/x86_64-linux-gnu/libLLVM.so.19.1

# Debian packages the tests and the demo need (Xvfb for PsychoPy windows, PsychoPy's audio/keyboard
# libraries, the xcb libraries Qt's X11 plugin needs for PsychoPy's dialogs, LLVM for Mitsuba,
# R with lme4, car, lmerTest and pbkrtest as the reference for the mixed models, a font,
# Chromium to screenshot the gap report in a real browser, SLURM and munge for the batch-cluster
# tests: tests/slurm_processes.py starts its own controller and node as the user who runs the
# tests, so the services the packages install need not run, and a policy-rc.d that stops them
# from starting does not fail the install).
DEB_PACKAGES := xvfb xauth libglu1-mesa libgl1 libegl1 libfontconfig1 libasound2 \
	libjack-jackd2-0 libportaudio2 libusb-1.0-0 libxrandr2 libxcursor1 libxi6 libxinerama1 \
	libxcb-icccm4 libxcb-keysyms1 libxcb-cursor0 \
	libllvm19 r-base-core r-cran-lme4 r-cran-car r-cran-lmertest r-cran-pbkrtest fonts-dejavu-core \
	chromium slurm-wlm munge
# Each Xvfb with its X authority file in PROJECT_HOME (`$(call XVFB_AS,name)`): xvfb-run then
# makes and removes no temporary folder of its own, whose removal once failed in CI (exit 5
# after the command had passed; docs/make_pictures.py and scripts/demo.sh do the same).
XVFB_AS = xvfb-run -a -f $(PROJECT_HOME)/Xauthority-$(1) -s "-screen 0 1280x1024x24"

.PHONY: help demo test test-fast docs system-deps venv lint bench clean-venv

help:
	@echo "make demo   - set up and run the whole pipeline on embedded defaults into $(OUT)/"
	@echo "make test   - set up and run the test suite (slow tests included)"
	@echo "make test-fast - the tests without those marked slow"
	@echo "make docs   - the documentation site into $(DOCS_HTML)/ (pictures made by the pipeline)"
	@echo "make lint   - ruff"

# apt-get only when something is missing, so a set-up machine needs no root.
system-deps:
	@missing=$$(for p in $(DEB_PACKAGES); do dpkg-query -W -f='$${Status}\n' $$p 2>/dev/null \
		| grep -q 'install ok installed' || echo $$p; done); \
	if [ -n "$$missing" ]; then \
		echo "installing Debian packages: $$missing"; \
		SUDO=$$( [ $$(id -u) -eq 0 ] || echo sudo ); \
		$$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq \
			--no-install-recommends $$missing; \
	fi

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test,docs]'
	touch $@

venv: $(STAMP)

# The suite runs in two parts at once, both always, failing if either fails: the real-time
# tests (PsychoPy windows paced by the frame clock, photometers on serial lines), one at a time
# at normal priority, and beside them the rest on TEST_WORKERS processes (pytest-xdist, each
# test file on one worker, so a module's fixtures are built once) at `nice` BACKGROUND_NICE, so
# the CPU goes to a real-time test whenever it needs it (the real-time tests mostly wait on the
# frame clock and the serial line, and a busy CPU at their own priority starves them); after
# the real-time part, still beside the parallel part, the documentation site. The parallel
# part's output is kept in PARALLEL_LOG and printed when it ends. `make test TESTS=path` runs just those tests, serially.
TEST_WORKERS ?= 2
BACKGROUND_NICE ?= 19
SERIAL_TESTS := tests/experiment tests/calibration
PARALLEL_LOG := $(PROJECT_HOME)/parallel-tests.log
TESTS ?=

test: system-deps $(STAMP)
	mkdir -p $(PROJECT_HOME)
	@if [ -n "$(TESTS)" ]; then \
		HOME=$(PROJECT_HOME) $(call XVFB_AS,tests) $(PY) -m pytest $(TESTS) $(PYTEST_ARGS); exit $$?; fi; \
	start=$$(date +%s); rm -f $(PARALLEL_LOG).rc; \
	echo "== tests in parallel ($(TEST_WORKERS) workers, nice $(BACKGROUND_NICE)), all but" \
		"$(SERIAL_TESTS), beside the real-time tests; output in $(PARALLEL_LOG) =="; \
	( HOME=$(PROJECT_HOME) nice -n $(BACKGROUND_NICE) $(call XVFB_AS,parallel) $(PY) -m pytest -n $(TEST_WORKERS) \
		--dist loadfile $(foreach d,$(SERIAL_TESTS),--ignore=$(d)) $(PYTEST_ARGS) \
		> $(PARALLEL_LOG) 2>&1; echo $$? > $(PARALLEL_LOG).rc ) & par=$$!; \
	sleep 3; \
	echo "== real-time tests, one at a time: $(SERIAL_TESTS) =="; \
	HOME=$(PROJECT_HOME) $(call XVFB_AS,realtime) $(PY) -m pytest $(SERIAL_TESTS) $(PYTEST_ARGS); second=$$?; \
	echo "== real-time part: exit $$second after $$(( $$(date +%s) - start )) s =="; \
	echo "== the documentation site, warnings as errors (beside the parallel part) =="; \
	$(DOCS_BUILD); third=$$?; \
	echo "== waiting for the parallel part after $$(( $$(date +%s) - start )) s =="; \
	wait $$par; first=$$(cat $(PARALLEL_LOG).rc 2>/dev/null || echo 1); \
	echo "== the parallel part's output (exit $$first, $$(( $$(date +%s) - start )) s) =="; \
	cat $(PARALLEL_LOG); \
	echo "== make test: parallel part exit $$first, real-time part exit $$second," \
		"docs exit $$third, $$(( $$(date +%s) - start )) s in all =="; \
	[ $$first -eq 0 ] && [ $$second -eq 0 ] && [ $$third -eq 0 ]

test-fast: PYTEST_ARGS += -m "not slow"
test-fast: test

# The documentation site (docs/): docs/make_pictures.py runs small versions of the pipeline's
# steps for the pictures (about a minute on 2 cores), then Sphinx builds every page again (-E)
# with warnings as errors. `make test` runs the same after its real-time tests.
DOCS_HTML := docs/_build/html
DOCS_BUILD = dstart=$$(date +%s); mkdir -p $(PROJECT_HOME); \
	HOME=$(PROJECT_HOME) $(PY) docs/make_pictures.py \
	&& HOME=$(PROJECT_HOME) $(PY) -m sphinx -b html -E -W --keep-going -q docs $(DOCS_HTML); \
	rc=$$?; echo "== docs: exit $$rc, $$(( $$(date +%s) - dstart )) s; open $(DOCS_HTML)/index.html =="; \
	[ $$rc -eq 0 ]

docs: system-deps $(STAMP)
	@$(DOCS_BUILD)

demo: system-deps $(STAMP)
	mkdir -p $(PROJECT_HOME)
	HOME=$(PROJECT_HOME) OUT=$(OUT) PY=$(PY) bash scripts/demo.sh

lint: $(STAMP)
	$(PY) -m ruff check .

bench: system-deps $(STAMP)
	mkdir -p $(PROJECT_HOME)
	for b in bench/*.py; do HOME=$(PROJECT_HOME) $(call XVFB_AS,bench) $(PY) $$b || exit 1; done

clean-venv:
	rm -rf $(VENV)
