#!/usr/bin/env bash
# Set up somtorch on a fresh machine: system library for Open3D, a virtual environment, the CPU
# build of torch FIRST (a plain `torch` requirement would pull a multi-GB CUDA build), then the rest.
# Idempotent: a second run only checks. Usage: bash scripts/setup.sh [extra, default "base"]
#   base: the package alone (scripts/run.sh); test: + the test extra (scripts/test.sh); bench, notebooks, ...
set -euo pipefail
cd "$(dirname "$0")/.."
EXTRA="${1:-base}"
PY="${PYTHON:-python3.11}"
command -v "$PY" >/dev/null 2>&1 || PY=python3

# 1. Open3D needs libusb-1.0 (Debian/Ubuntu: libusb-1.0-0).
# (the list is read whole first: `ldconfig -p | grep -q` under pipefail fails now and then, when grep
#  exits at the first match and ldconfig dies of SIGPIPE)
LIBS="$(ldconfig -p 2>/dev/null || true)"
if [[ "$LIBS" != *libusb-1.0.so.0* ]]; then
  if command -v apt-get >/dev/null 2>&1; then
    SUDO=""; [ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1 && SUDO="sudo"
    echo "[setup] installing libusb-1.0-0 for Open3D"
    $SUDO apt-get update -qq && $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0 >/dev/null
  else
    echo "[setup] WARNING: libusb-1.0 not found and no apt-get: install it, or Open3D (PLY output) will not import" >&2
  fi
fi

# pip's notes about configured find-links folders that do not exist on this machine are noise
quiet_pip() { grep -v -E "^WARNING: Location .* is ignored" || true; }

# 2. Virtual environment.
VPY=.venv/bin/python
if [ ! -x "$VPY" ]; then
  "$PY" -m venv .venv
  $VPY -m pip install -q --upgrade pip >/dev/null 2>&1 || true
fi

# 3. torch 2.13.0, CPU build, before anything else.
if ! $VPY -c 'import torch, sys; sys.exit(0 if torch.__version__.startswith("2.13.0") else 1)' 2>/dev/null; then
  echo "[setup] installing torch==2.13.0 (CPU)"
  if [ -n "${SOMTORCH_TORCH_INDEX:-}" ]; then
    $VPY -m pip install -q "torch==2.13.0" --index-url "$SOMTORCH_TORCH_INDEX" 2>&1 | quiet_pip
  elif ls /opt/wheels/torch-2.13.0+cpu-*.whl >/dev/null 2>&1; then
    $VPY -m pip install -q "torch==2.13.0" --find-links /opt/wheels 2>&1 | quiet_pip
  else
    $VPY -m pip install -q "torch==2.13.0" --index-url https://download.pytorch.org/whl/cpu 2>&1 | quiet_pip
  fi
fi

# 4. The project and its other dependencies (torch already satisfies the range), once. The stamp
#    holds the hash of pyproject.toml and the extras installed so far: a request for an extra already
#    there (or for the base, which every extra includes) starts at once; a new extra installs it.
STAMP=.venv/.somtorch-setup
HASH="$(sha256sum pyproject.toml | cut -c1-16)"
{ read -r OLD_HASH OLD_EXTRAS <"$STAMP"; } 2>/dev/null || true  # (no stamp yet: a fresh clone)
[ "${OLD_HASH:-}" = "$HASH" ] || OLD_EXTRAS=""
HAVE=",${OLD_EXTRAS:-base},"
NEED=0
for e in ${EXTRA//,/ }; do
  [ "$e" = base ] || [[ "$HAVE" == *",$e,"* ]] || NEED=1
done
if [ "${OLD_HASH:-}" = "$HASH" ] && [ "$NEED" = 0 ] && $VPY -c 'import somtorch' 2>/dev/null; then
  exit 0
fi
if [ "$EXTRA" = base ]; then TARGET="."; else TARGET=".[$EXTRA]"; fi
echo "[setup] installing somtorch${TARGET#.}"
PIP_LOG="$(mktemp)"
PIP_STATUS=0
$VPY -m pip install -q -e "$TARGET" >"$PIP_LOG" 2>&1 || PIP_STATUS=$?
grep -v -E "^WARNING: Location|is ignored|^ " "$PIP_LOG" || true  # drop setuptools banners
rm -f "$PIP_LOG"
if [ "$PIP_STATUS" -ne 0 ]; then
  echo "[setup] ERROR: pip install -e \"$TARGET\" failed (status $PIP_STATUS); nothing recorded, run again" >&2
  exit "$PIP_STATUS"
fi
if [[ ",$EXTRA," == *",test,"* ]]; then
  # the test oracle of somtorch.saliency_metrics; --no-deps: its metadata pins numpy < 2.3.5 and
  # scikit-image < 0.26, which it does not need (tests/test_saliency_metrics.py checks it works)
  $VPY -m pip install -q --no-deps "pysodmetrics==1.6.2" 2>&1 | quiet_pip || echo "[setup] WARNING: pysodmetrics not installed; its oracle test will skip" >&2
fi
if [[ ",$EXTRA," == *",bench,"* ]]; then
  # benchmark-only peers that pip cannot resolve on its own (benchmarks/README.md): fastersom 0.6.0
  # declares Python >= 3.12 but is pure Python; somoclu's sdist needs numpy at build time and must
  # not try its CUDA build
  $VPY -m pip install -q --no-deps --ignore-requires-python "fastersom==0.6.0" 2>&1 | quiet_pip \
    || echo "[setup] WARNING: fastersom not installed; bench_core.py reports it missing" >&2
  CUDAHOME=/nonexistent $VPY -m pip install -q --no-build-isolation --no-deps "somoclu==1.7.6" 2>&1 | quiet_pip \
    || echo "[setup] WARNING: somoclu not built; bench_core.py reports it missing" >&2
fi
$VPY -c 'import somtorch, torch; print(f"[setup] ok: somtorch {somtorch.__version__}, torch {torch.__version__}")'
ALL="$(echo "${OLD_EXTRAS:-base},$EXTRA" | tr ',' '\n' | { grep -v -x -e '' -e base || true; } | sort -u | paste -sd, -)"
echo "$HASH ${ALL:-base}" > "$STAMP"
