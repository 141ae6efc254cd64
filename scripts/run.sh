#!/usr/bin/env bash
# Installs everything into .venv (made if missing) and starts the dashboard on 127.0.0.1:8000 with the
# simulated robots and the sample sessions (data in ./data). Extra arguments go to `calib serve`.
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m venv .venv
.venv/bin/pip install -q --upgrade pip
.venv/bin/pip install -q -e .
exec .venv/bin/calib serve "$@"
