#!/usr/bin/env bash
# Install everything the test suite needs on a fresh machine; the README's test command is
#   ./scripts/install-test-deps.sh && python -m pytest
#
# pip installs the package with its test and peer extras (FilterPy, Stone Soup and
# pyroomacoustics are compared against in the tests). The one thing pip cannot install is the
# software Vulkan driver the headless Rerun viewer test renders with (Debian's
# mesa-vulkan-drivers); it is installed with apt-get when missing.
set -euo pipefail
cd "$(dirname "$0")/.."

if command -v dpkg >/dev/null 2>&1 && ! dpkg -s mesa-vulkan-drivers >/dev/null 2>&1; then
  if [ "$(id -u)" -eq 0 ]; then sudo=""; elif command -v sudo >/dev/null 2>&1; then sudo="sudo"; else
    echo "scripts/install-test-deps.sh: the headless viewer test needs Debian's mesa-vulkan-drivers; install it as root" >&2
    exit 2
  fi
  echo "scripts/install-test-deps.sh: installing mesa-vulkan-drivers (software Vulkan for the headless viewer test)" >&2
  ($sudo apt-get update -qq && DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq mesa-vulkan-drivers) >/dev/null
fi

python -m pip install --quiet ".[test,peers]"
