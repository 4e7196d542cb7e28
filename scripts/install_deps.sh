#!/usr/bin/env bash
# Installs the Debian packages deblur_sr_mvs needs, skipping those already
# installed (a warm machine pays nothing). Safe to run repeatedly.
# Usage: scripts/install_deps.sh [--core-only | --viewer]
#   --viewer: also rviz, Xvfb and ImageMagick (scripts/rviz_screenshot.sh)
set -euo pipefail

core_pkgs=(cmake g++ make pkg-config libopencv-dev libeigen3-dev libceres-dev
           googletest libgtest-dev libyaml-cpp-dev nlohmann-json3-dev libcli11-dev
           libopencv-video-dev libopencv-contrib-dev ccache)
ros_pkgs=(catkin catkin-tools ros-core rosbash rospack-tools ros-message-generation
          ros-message-runtime libroscpp-dev librosconsole-dev libstd-msgs-dev
          libsensor-msgs-dev libgeometry-msgs-dev ros-std-msgs ros-sensor-msgs
          ros-geometry-msgs python3-std-msgs python3-sensor-msgs python3-geometry-msgs
          python3-tf2-msgs libtf2-ros-dev libtf2-geometry-msgs-dev libtf2-eigen-dev
          libcv-bridge-dev libimage-transport-dev
          libdynamic-reconfigure-config-init-mutex-dev python3-dynamic-reconfigure
          librostest-dev python3-rostest librosbag-dev libnav-msgs-dev python3-nav-msgs
          libdiagnostic-updater-dev libnodeletlib-dev libnodelet-dev libnodeletlib-tools
          libcamera-calibration-parsers-dev libopencv-superres-dev)

viewer_pkgs=(rviz xvfb xauth imagemagick)

pkgs=("${core_pkgs[@]}")
[ "${1:-}" = "--core-only" ] || pkgs+=("${ros_pkgs[@]}")
[ "${1:-}" = "--viewer" ] && pkgs+=("${viewer_pkgs[@]}")

missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  echo "install_deps: all ${#pkgs[@]} Debian packages present"
  exit 0
fi
echo "install_deps: installing ${#missing[@]} missing Debian packages: ${missing[*]}"
SUDO=""
[ "$(id -u)" -eq 0 ] || SUDO="sudo"
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
