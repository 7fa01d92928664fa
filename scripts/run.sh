#!/usr/bin/env bash
# Set up (if needed) and run the main job: the whole pipeline on the embedded Motorcycle scene.
# Extra arguments are Hydra overrides, e.g.: bash scripts/run.sh data=kitti2015 ensemble=20
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh base   # the package alone: no test extra (Ray, Optuna, pytest)
exec .venv/bin/python -m experiments.run "$@"
