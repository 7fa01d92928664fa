#!/usr/bin/env bash
# Data-parallel SOM training of the main job on SLURM: one task per process, several nodes.
#   sbatch --nodes=2 --ntasks-per-node=4 scripts/slurm_distributed.sh train.parallel=data data=kitti2015
# Each task runs experiments.distributed (RANK / WORLD_SIZE come from SLURM_PROCID / SLURM_NTASKS);
# rank 0 writes the outputs under paths.output_dir/distributed/. Edit the #SBATCH lines for your site.
#SBATCH --job-name=somtorch-dist
#SBATCH --time=01:00:00
#SBATCH --cpus-per-task=4
set -euo pipefail
cd "${SLURM_SUBMIT_DIR:-$(dirname "$0")/..}"
export MASTER_ADDR="$(scontrol show hostnames "$SLURM_JOB_NODELIST" | head -n 1)"
export MASTER_PORT="${MASTER_PORT:-29500}"
export OMP_NUM_THREADS="${SLURM_CPUS_PER_TASK:-1}"
srun .venv/bin/python -m experiments.distributed "$@"
