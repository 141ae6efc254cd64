#!/usr/bin/env bash
# Installs everything into .venv (made if missing; pip runs only when pyproject.toml changed since the last
# install, scripts/venv.sh) and starts the dashboard on 127.0.0.1:8000 with the simulated robots and the
# sample sessions (data in ./data). Extra arguments go to `calib serve`.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/venv.sh
ensure_venv . '.[test,ros2,naoqi]' '.[test,ros2]' '.[test]'
exec .venv/bin/calib serve "$@"
