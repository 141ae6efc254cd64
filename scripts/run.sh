#!/usr/bin/env bash
# Installs everything into .venv (made if missing) and runs the papers' experiments on the simulated
# robots. (When the dashboard lands, this starts it on the sample sessions instead.)
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m venv .venv
.venv/bin/pip install -q --upgrade pip
.venv/bin/pip install -q -e .
.venv/bin/python benchmarks/papers.py --quick "$@"
