#!/usr/bin/env bash
# Installs the test dependencies into .venv (made if missing) and runs the whole test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m venv .venv
.venv/bin/pip install -q --upgrade pip
.venv/bin/pip install -q -e '.[test]'
.venv/bin/ruff format --check calib_core app tests benchmarks
.venv/bin/ruff check calib_core app tests benchmarks
.venv/bin/python -m pytest -q "$@"
