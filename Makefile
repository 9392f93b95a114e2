# Two commands for a newcomer: `make test` and `make table1`.
# Each creates .venv if missing, installs the package (editable, with test extras)
# and the system packages: libusb-1.0-0 (Open3D needs it) and chromium (the viewer's screenshots and
# its tests load the page in headless Chromium). A second run is quick.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp

.PHONY: setup syslibs test table1 bench clean-venv

# Reproducible floating point on x86-64: the retargeting and the demonstration fits are non-convex, and the
# last-bit differences of numpy's and OpenBLAS's AVX-512 kernels lead them elsewhere (chips' retargeting
# MSE 988 instead of 856 mm^2). Every x86-64 machine then computes with the AVX2 kernels the shipped
# demonstrations and the committed Table I were made with (`pbdgrasp` records which in its caches and
# report). Set either variable yourself to override.
ifeq ($(shell uname -m),x86_64)
export OPENBLAS_CORETYPE ?= Haswell
export NPY_DISABLE_CPU_FEATURES ?= X86_V4 AVX512_ICL AVX512_SPR AVX512F AVX512CD AVX512_SKX AVX512_CLX AVX512_CNL
endif

setup: syslibs $(STAMP)

# $(call apt_need,PACKAGE,WHY,CHECK): run CHECK; if it fails, install PACKAGE with apt-get as root, or
# stop with one line saying what to install.
define apt_need
	@if ! $(3); then \
	  if [ "$$(id -u)" = "0" ] && command -v apt-get >/dev/null; then \
	    echo "installing $(1) ($(2))"; \
	    (apt-get install -y -q $(1) >/dev/null 2>&1 || \
	     (apt-get update -q >/dev/null && apt-get install -y -q $(1) >/dev/null)) || \
	     { echo "error: could not install $(1) with apt-get"; exit 1; }; \
	  else \
	    echo "error: $(2): install the system package $(1) (sudo apt-get install $(1)) and rerun"; \
	    exit 1; \
	  fi; \
	fi
endef

syslibs:
	$(call apt_need,libusb-1.0-0,needed by Open3D,/sbin/ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0')
	$(call apt_need,chromium,the viewer's screenshots and tests,command -v chromium >/dev/null)

$(STAMP): pyproject.toml .ci/constraints.txt
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -c .ci/constraints.txt -e '.[test]'
	@touch $(STAMP)

test: setup
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	MPLBACKEND=Agg $(BIN)/python -m pytest --durations=15
	MPLBACKEND=Agg $(BIN)/python -m pytest --nbmake notebooks/

table1: setup
	$(BIN)/pbdgrasp table1 --seed 0 --planners learned,baseline,bidirectional,goal_region,ompl \
	  --db results/table1.sqlite --cache-dir results/cache --report-dir results

bench: setup
	$(BIN)/pbdgrasp bench

clean-venv:
	rm -rf $(VENV)
