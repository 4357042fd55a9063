#!/usr/bin/env bash
# The GPU check, one command for a session that has a CUDA machine (issue 38): the CUDA
# tests, then `runtime-bench --device cuda` on the whole hybrid, with a CPU baseline on the
# same machine (the same recordings, 2 threads). Logs go to $OUT (default out/gpu_check).
# Expects python3 with torch (CUDA), numpy, pyyaml, opencv and numba already installed, as
# on the lent machines; installs this checkout
# without dependencies or network. The recordings folder (default data/dev, the ten smoke
# recordings) must fit the device's transfer limit; docs/results.md (sixteenth session) gives
# the recipe of data/gpu5, five broad recordings.
set -u
OUT=${OUT:-out/gpu_check}
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1
recs=${1:-data/dev}
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv | tee "$OUT/gpu.txt"
python3 -m pip install -q --no-deps --no-build-isolation --no-index -e . >"$OUT/install.log" 2>&1 \
  || { echo "install failed"; tail -20 "$OUT/install.log"; exit 1; }
python3 -c "import torch; print('torch', torch.__version__, torch.cuda.get_device_name())"
extra=()
[ -d "$recs" ] && extra=(--hybrid-recordings "$recs")
echo "== runtime-bench --device cuda =="
timeout "${BENCH_S:-240}" python3 -m depthmocap.bench --device cuda "${extra[@]}" 2>&1 \
  | tee "$OUT/bench_cuda.log"
echo "== runtime-bench --device cpu (baseline, same machine, 2 threads) =="
timeout "${BASE_S:-150}" python3 -m depthmocap.bench --device cpu --threads 2 "${extra[@]}" 2>&1 \
  | tee "$OUT/bench_cpu.log"
echo "== CUDA tests =="
timeout "${TEST_S:-150}" python3 -m pytest -q -p no:cacheprovider -k cuda tests 2>&1 \
  | tee "$OUT/tests_cuda.log" | tail -25
timeout 60 python3 -m pytest -q -p no:cacheprovider -m gpu tests 2>&1 \
  | tee "$OUT/tests_gpu.log" | tail -8
echo "== host syncs per frame, by source line =="
timeout "${SYNC_S:-90}" python3 -m depthmocap.bench.cuda_syncs --frames 10 --rows 25 2>&1 \
  | tee "$OUT/syncs.log"
