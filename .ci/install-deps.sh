#!/usr/bin/env bash
# Installs the Debian packages the pipeline needs, if any is missing:
# gmsh (meshing), FreeFEM with its plugins (cross-checks), libhdf5 (result
# files), pkg-config and a C toolchain (for the hdf5 crate), ParaView and
# Chromium (the tests render result files and report pages with them), and
# Snakemake from PyPI in a venv (tests/study_workflow.rs runs a study through
# it; the tests find it at $OBSTACLE_SNAKEMAKE, default the venv's).
# Uses sudo when not root. Rust (cargo ≥ 1.89) must already be installed.
set -euo pipefail
packages=(gmsh freefem++ libfreefem++ libhdf5-dev hdf5-tools pkg-config build-essential
          paraview python3-paraview xvfb xauth chromium python3-venv)
missing=()
for p in "${packages[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
    echo "installing: ${missing[*]}"
    sudo=""
    [ "$(id -u)" -eq 0 ] || sudo="sudo"
    export DEBIAN_FRONTEND=noninteractive
    $sudo apt-get update -qq
    $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi
# Snakemake, pinned (8.30.0 runs on Python ≥ 3.11, Debian 12's python3).
venv=/opt/obstacle-venv
snakemake_version=8.30.0
if [ "$("$venv/bin/snakemake" --version 2>/dev/null)" != "$snakemake_version" ]; then
    echo "installing: snakemake $snakemake_version in $venv"
    sudo=""
    [ "$(id -u)" -eq 0 ] || sudo="sudo"
    $sudo python3 -m venv "$venv"
    $sudo "$venv/bin/pip" install -q "snakemake==$snakemake_version"
fi
if ! command -v cargo >/dev/null 2>&1; then
    echo "error: cargo not found: install Rust (https://rustup.rs), version 1.89 or newer" >&2
    exit 1
fi
