# Two entry points for a fresh machine that has only python3:
#   make run   - create .venv, install imucald, run the main job
#   make test  - create .venv, install imucald with its test extras, run the suite
#   make docs  - install the docs extra, regenerate the generated pages and pictures, build the
#                site into site/ with mkdocs --strict (a broken link or a missing page fails)
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
TSTAMP := $(VENV)/.installed-test
DSTAMP := $(VENV)/.installed-docs

.PHONY: run test test-system bench clean test-deps install uninstall docs

$(BIN)/python:
	@$(PYTHON) -c 'import sys; sys.exit(sys.version_info < (3, 9))' || \
	  { echo "imucald needs Python >= 3.9 (found $$($(PYTHON) --version 2>&1))"; exit 1; }
	@$(PYTHON) -m venv $(VENV) || \
	  { echo "could not create a venv: on Debian/Raspberry Pi OS run 'sudo apt install python3-venv' and retry"; rm -rf $(VENV); exit 1; }
	@$(BIN)/python -m pip install --quiet --upgrade pip

SOURCES := pyproject.toml $(shell find imucald -name '*.py' 2>/dev/null)

# A regular (not editable) install, redone whenever a source file changes.
$(STAMP): $(BIN)/python $(SOURCES)
	$(BIN)/python -m pip install --quiet .
	@touch $@

$(TSTAMP): $(BIN)/python $(SOURCES)
	$(BIN)/python -m pip install --quiet '.[test]'
	@touch $@ $(STAMP)

$(DSTAMP): $(BIN)/python $(SOURCES)
	$(BIN)/python -m pip install --quiet '.[docs]'
	@touch $@

# the reference pages made from the parser and the config schema, the pictures made by
# imucald's own commands (tools/gen_docs.py, ~10 s), then the site, offline and strict
docs: $(DSTAMP)
	$(BIN)/python tools/gen_docs.py --man build/man
	$(BIN)/python -m mkdocs build --strict   # not --quiet: it hides the warnings that --strict counts

# The daemon for 200 s: on the I2C bus when one exists, else on the emulated board,
# which a virtual hand moves through 30 orientations.  State and sockets stay in ./.imucald/.
run: $(STAMP)
	$(BIN)/imucald run --state-dir .imucald/state --runtime-dir .imucald/run --echo --duration 200

# pytest exits 5 when it collected no test: that is a failure too (make stops on any non-zero exit).
# Two workers (pytest-xdist), each test file on one worker (module fixtures computed once):
# the suite is ~5 min in one process on a 2-core machine, ~half of it waiting on the daemons
# and CLI processes it starts.
test: $(TSTAMP) test-deps
	$(BIN)/python -m pytest -q -n 2 --dist loadfile

# The MQTT tests run a real broker, Debian's mosquitto: installed here where we may (root
# with apt-get), else those tests skip and say why.
test-deps:
	@if ! command -v mosquitto >/dev/null 2>&1 && [ ! -x /usr/sbin/mosquitto ]; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "installing mosquitto (apt-get) for the MQTT tests"; \
	    { apt-get update -q && DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends mosquitto; } >/dev/null 2>&1 \
	      || echo "could not install mosquitto: the MQTT tests will skip"; \
	  else echo "mosquitto is missing (sudo apt-get install mosquitto): the MQTT tests will skip"; fi; \
	fi

# The service under a real systemd (tests/test_system.py): a Debian bookworm container booted
# with systemd-nspawn, this checkout installed in it with `make install`, every unit checked.
# Needs root, systemd-nspawn (apt-get install systemd-container) and, the first time,
# debootstrap; the tree is cached in /var/cache/imucald-systest (IMUCALD_SYSTEST_CACHE).
# Where the host cannot boot a container it skips, and the summary says why.
test-system: $(TSTAMP)
	@if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1 && \
	  { ! command -v systemd-nspawn >/dev/null 2>&1 || ! command -v debootstrap >/dev/null 2>&1; }; then \
	  echo "installing systemd-container and debootstrap (apt-get) for the system test"; \
	  { apt-get update -q && DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends \
	      systemd-container debootstrap; } >/dev/null 2>&1 \
	    || echo "could not install systemd-container/debootstrap: the system test will skip"; \
	fi
	IMUCALD_SYSTEM_TEST=1 $(BIN)/python -m pytest -q -rs -p no:cacheprovider tests/test_system.py

bench: $(TSTAMP)
	$(BIN)/python bench/speed.py

# As a system service (README "Run as a service"): the venv in PREFIX (/opt/imucald) with the
# mqtt extra, /etc/imucald/imucald.yaml where there is none, the units in /etc/systemd/system,
# an i2c udev rule where none exists.  DESTDIR=DIR stages into DIR and changes nothing else;
# NO_VENV=1 lays out the files only; `make uninstall` keeps the configuration and the
# calibrations unless PURGE=1; BINDIR (/usr/local/bin) gets a link to imucald.
# packaging/install.sh does the work.
INSTALL_VARS = DESTDIR="$(DESTDIR)" PREFIX="$(or $(PREFIX),/opt/imucald)" PYTHON="$(PYTHON)" \
	SYSCONFDIR="$(or $(SYSCONFDIR),/etc/imucald)" UNITDIR="$(or $(UNITDIR),/etc/systemd/system)" \
	UDEVDIR="$(or $(UDEVDIR),/etc/udev/rules.d)" DOCDIR="$(or $(DOCDIR),/usr/share/doc/imucald)" \
	BINDIR="$(or $(BINDIR),/usr/local/bin)" \
	EXTRAS="$(if $(filter undefined,$(origin EXTRAS)),mqtt,$(EXTRAS))" NO_VENV="$(NO_VENV)" PURGE="$(PURGE)"

install:
	@$(INSTALL_VARS) sh packaging/install.sh install

uninstall:
	@$(INSTALL_VARS) sh packaging/install.sh uninstall

clean:
	rm -rf $(VENV) build *.egg-info site
