# Source this file (bash): `source scripts/env.sh`. It activates the project's .venv (ROS 2 Kilted from PyPI,
# torch, onnxruntime, ...) and the colcon overlay in install/, so that the tactile_* Python packages, the
# tactile_msgs messages and every command-line tool of the project (tactile-sim, tactile-fusion, the nodes)
# are available. Run `make setup` once first.

_tactile_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
if [ ! -f "$_tactile_root/.venv/bin/activate" ] || [ ! -f "$_tactile_root/install/setup.bash" ]; then
    echo "scripts/env.sh: no built workspace in $_tactile_root; run 'make setup' first" >&2
    unset _tactile_root
    return 1 2>/dev/null || exit 1
fi
# The venv and colcon scripts read unset variables: allow that while sourcing them, restore the caller's setting.
case $- in *u*) _tactile_nounset=1; set +u ;; *) _tactile_nounset= ;; esac
# shellcheck disable=SC1091
source "$_tactile_root/.venv/bin/activate"
# The ROS wheels install their ament index and CMake configs into the venv itself.
case ":${AMENT_PREFIX_PATH:-}:" in *":$VIRTUAL_ENV:"*) ;; *) export AMENT_PREFIX_PATH="$VIRTUAL_ENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}" ;; esac
case ":${CMAKE_PREFIX_PATH:-}:" in *":$VIRTUAL_ENV:"*) ;; *) export CMAKE_PREFIX_PATH="$VIRTUAL_ENV${CMAKE_PREFIX_PATH:+:$CMAKE_PREFIX_PATH}" ;; esac
# The overlay puts the packages on PYTHONPATH and the message libraries on LD_LIBRARY_PATH; the latter must be
# set before Python starts, which is why this is a file to source and not something Python could do itself.
# shellcheck disable=SC1091
source "$_tactile_root/install/setup.bash"
[ -n "$_tactile_nounset" ] && set -u
# Node executables live in install/<pkg>/lib/<pkg>, where `ros2 run` looks for them; put them on PATH too.
for _tactile_dir in "$_tactile_root"/install/tactile_*/lib/tactile_*; do
    case ":$PATH:" in *":$_tactile_dir:"*) ;; *) [ -d "$_tactile_dir" ] && PATH="$_tactile_dir:$PATH" ;; esac
done
export PATH
# Keep DDS discovery on this machine unless the user chose otherwise.
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
unset _tactile_root _tactile_dir _tactile_nounset
