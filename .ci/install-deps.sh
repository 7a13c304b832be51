#!/usr/bin/env bash
# Installs the Debian packages the pipeline needs, if any is missing:
# gmsh (meshing), FreeFEM with its plugins (cross-checks), libhdf5 (result
# files), pkg-config and a C toolchain (for the hdf5 crate), ParaView and
# Chromium (the tests render result files and report pages with them), and
# Snakemake from PyPI in a venv (tests/study_workflow.rs runs a study through
# it; the tests find it at $OBSTACLE_SNAKEMAKE, default the venv's), and Slurm
# with munge and Snakemake's Slurm executor (tests/study_slurm.rs runs a study
# on a one-node cluster, pipelines/slurm/local-cluster.sh; `ss` of iproute2
# finds its free ports).
# Uses sudo when not root. Rust (cargo ≥ 1.89) must already be installed.
set -euo pipefail
packages=(gmsh freefem++ libfreefem++ libhdf5-dev hdf5-tools pkg-config build-essential
          paraview python3-paraview xvfb xauth chromium python3-venv
          slurm-wlm munge iproute2)
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
# Snakemake and its Slurm executor, pinned: snakemake 8.30.0 runs on Python
# ≥ 3.11 (Debian 12's python3); the executor 2.8.0 needs
# snakemake-interface-executor-plugins 9.4 (snakemake 8.30.0's) and its job
# step plugin ≥ 0.6.0. The job step 0.6.1 removes every SLURM_* variable
# before it starts a run with srun inside the job, SLURM_CONF included, so
# srun finds no configuration on a cluster that names it there (the local
# one); 0.6.0 keeps the environment.
venv=/opt/obstacle-venv
snakemake_version=8.30.0
slurm_plugin_version=2.8.0
jobstep_version=0.6.0
installed() {
    "$venv/bin/python" -c 'import importlib.metadata as m, sys; print(m.version(sys.argv[1]))' "$1" 2>/dev/null || true
}
if [ "$(installed snakemake)" != "$snakemake_version" ] \
    || [ "$(installed snakemake-executor-plugin-slurm)" != "$slurm_plugin_version" ] \
    || [ "$(installed snakemake-executor-plugin-slurm-jobstep)" != "$jobstep_version" ]; then
    echo "installing: snakemake $snakemake_version, snakemake-executor-plugin-slurm $slurm_plugin_version" \
        "(job step $jobstep_version) in $venv"
    sudo=""
    [ "$(id -u)" -eq 0 ] || sudo="sudo"
    [ -x "$venv/bin/pip" ] || $sudo python3 -m venv "$venv"
    $sudo "$venv/bin/pip" install -q "snakemake==$snakemake_version" \
        "snakemake-executor-plugin-slurm==$slurm_plugin_version" \
        "snakemake-executor-plugin-slurm-jobstep==$jobstep_version"
fi
if ! command -v cargo >/dev/null 2>&1; then
    echo "error: cargo not found: install Rust (https://rustup.rs), version 1.89 or newer" >&2
    exit 1
fi
