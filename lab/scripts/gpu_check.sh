#!/usr/bin/env bash
# The GPU checks behind README *GPU backends*: the GPU-against-CPU test, the network benchmark
# on the GPU and on flex, and the bundled SLAM (FPFDCNN + SDFCNN, RGB-D) on both. Build first
# (or copy these binaries onto the GPU machine):
#
#   cargo build --release --features wgpu --bin bench --bin slam
#   cargo test --release --features wgpu --test gpu_backends --no-run   # prints the test binary
#
# Usage: lab/scripts/gpu_check.sh [BIN_DIR] [TEST_BINARY] [OUT_DIR] [BACKEND]
# Without TEST_BINARY the test is skipped (it runs from the repository root it was built in).
# Exits 1 when a step failed or ran past GPU_CHECK_TIMEOUT.
# Everything printed is also written under OUT_DIR (default runs/gpu_check).
set -u -o pipefail
status=0
bin=${1:-target/release}
test_bin=${2:-}
out=${3:-runs/gpu_check}
gpu=${4:-wgpu}
limit=${GPU_CHECK_TIMEOUT:-300}   # seconds per command
mkdir -p "$out"
{
    date -u
    nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader 2>/dev/null
    echo "$(nproc) CPU threads: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2)"
} | tee "$out/machine.txt"
if [ -n "$test_bin" ]; then
    SDF_SLAM_REQUIRE_GPU=1 timeout "$limit" "$test_bin" --nocapture --test-threads 1 2>&1 | tee "$out/gpu_backends.log" || status=1
fi
timeout "$limit" "$bin/bench" --backend "$gpu" --backend flex --runs 5 --warmup 2 \
    --case fpfdcnn-infer --case fpfdcnn-detect --case sdfcnn-infer 2>&1 | tee "$out/bench.log" || status=1
for b in "$gpu" flex; do
    timeout "$limit" "$bin/slam" --backend "$b" --out "$out/slam_$b" 2>&1 | tee "$out/slam_$b.log" || status=1
done
exit $status
