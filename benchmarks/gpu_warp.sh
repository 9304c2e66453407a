#!/bin/bash
# MuJoCo Warp on an NVIDIA GPU (issue 35), prepared to run in under 10 minutes: env steps/s end
# to end and raw for 1,024, 4,096 and 8,192 arenas (benchmarks/train_speed.py), then the first
# three minutes of a tracker on the synthetic adversary's clips with 4,096 arenas, gated every
# 10 iterations (benchmarks/tracker_gate.py). Each figure goes to $OUT (default /tmp/gpu_warp).
#
# Run from the repository root: `bash benchmarks/gpu_warp.sh`. It needs this project's packages
# (mujoco, mujoco-warp and warp-lang among them) in the python3 it finds, and the dev assets
# (data/assets: `make` fetches them). Warp compiles its CUDA kernels on the first step of each
# new model, into its kernel cache.
set -euo pipefail
cd "$(dirname "$0")/.."
out=${OUT:-/tmp/gpu_warp}
mkdir -p "$out"
export PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,memory.total --format=csv | tee "$out/gpu.txt"
for envs in 1024 4096 8192; do
  timeout 140 python3 benchmarks/train_speed.py --stepping warp --device cuda --envs "$envs" \
    | tee "$out/train_speed_$envs.txt" || echo "train_speed --envs $envs: exit $?"
done
timeout 150 python3 benchmarks/tracker_gate.py "$out/tracker" --stepping warp --device cuda \
  --envs 4096 --minutes 2 --gate-every 10 --checkpoint-every 10 --keep-going \
  | tee "$out/tracker.txt" || echo "tracker_gate: exit $?"
