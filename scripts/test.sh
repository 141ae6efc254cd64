#!/usr/bin/env bash
# Installs the test dependencies into .venv (made if missing; pip runs only when pyproject.toml changed
# since the last install, scripts/venv.sh), Debian's chromium and Mesa's EGL (its WebGL without a GPU, faster
# than chromium's own: tests/browser.py) for the browser tests (apt-get, when missing), and runs ruff and the
# whole test suite: what CI runs.
#   --fast  ruff, then the tests marked neither slow, browser nor subprocess (pyproject.toml): calib_core and
#           the API in-process, in under a minute. Options after it go to pytest.
# The tests run in two pytest-xdist workers (a test module stays in one worker, where its module fixtures live);
# TEST_WORKERS=N chooses another number, TEST_WORKERS=0 runs them in this process.
set -euo pipefail
cd "$(dirname "$0")/.."
FAST=false
if [ "${1:-}" = "--fast" ]; then
    FAST=true
    shift
fi
if ! $FAST && { ! command -v chromium >/dev/null 2>&1 || [ ! -e /usr/share/glvnd/egl_vendor.d/50_mesa.json ]; }; then
    SUDO=$([ "$(id -u)" = 0 ] && echo "" || echo "sudo")
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq chromium libegl-mesa0 libgl1-mesa-dri >/dev/null
fi
# Python may cache the compiled modules (where PYTHONDONTWRITEBYTECODE forbids it, each of the suite's hundreds of
# `calib` processes compiled the project's modules again: 0.4 s of a desk's start, and pytest rewrote every test
# module's assertions at each run).
unset PYTHONDONTWRITEBYTECODE
source scripts/venv.sh
ensure_venv '.[test,ros2,naoqi]'
.venv/bin/ruff format --check calib_core app tests benchmarks
.venv/bin/ruff check calib_core app tests benchmarks
WORKERS=(-n "${TEST_WORKERS:-2}" --dist loadfile --no-loadscope-reorder)  # modules longest first: tests/conftest.py
# The plugins by name, not by their packages' entry points: for those pytest rewrites the assertions of every module
# of hypothesis and schemathesis, in each of its processes in a new environment (3 s of each one's start, as CI has).
export PYTEST_DISABLE_PLUGIN_AUTOLOAD=1
# One BLAS thread a process: the workers and the processes they start already share the cores, and a second thread
# spins more CPU than it saves (the fast lane 70 -> 66 s of CPU; a plan, benchmarks/README.md).
export OPENBLAS_NUM_THREADS=1
PLUGINS=(-p xdist.plugin -p _hypothesis_pytestplugin -p schemathesis.pytest.plugin)
if $FAST; then
    .venv/bin/python -m pytest -q "${PLUGINS[@]}" "${WORKERS[@]}" -m "not slow and not browser and not subprocess" "$@"
else
    .venv/bin/python -m pytest -q "${PLUGINS[@]}" "${WORKERS[@]}" --durations=25 "$@"
fi
