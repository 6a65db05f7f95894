#!/usr/bin/env bash
# Build the colcon workspace (src/) against the ROS 2 wheels in .venv. Called by `make setup`.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
# shellcheck disable=SC1091
source .venv/bin/activate
export AMENT_PREFIX_PATH="$VIRTUAL_ENV" CMAKE_PREFIX_PATH="$VIRTUAL_ENV"
# --symlink-install: Python sources and config files in install/ are links to src/, so edits need no rebuild.
colcon --log-base build/log build --symlink-install --base-paths src --build-base build --install-base install \
    --event-handlers console_cohesion- summary+ status- "$@"
