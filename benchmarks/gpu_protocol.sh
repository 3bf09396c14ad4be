#!/bin/bash
# The densification protocol's GPU rows on a lent CUDA machine in one call: gsplat fits every 3DGS at its
# full schedule (1500 steps), the network trains on CUDA, and every capture x seed runs as its own
# `sparself evaluate --seeds 1 --first-seed k` at once (a shared deadline stops them all, so that the
# seeds which finished come back). Combine them afterwards as a batch does (mean ± std over seeds).
#   bash benchmarks/gpu_protocol.sh DATA OUT [SECONDS]   # DATA holds llff_bird; samples/bird is in the repo
# Without pycolmap on the device, give llff_bird as images/ + poses_bounds.npy (no sparse/).
set -u
DATA=$1 OUT=$2 LIMIT=${3:-520}
source "$(dirname "$0")/gpu_start.sh"
C="--quick --seeds 1 --no-weighted --densify-baselines flow --recon gsplat --device cuda -q"
for spec in "b9 $DATA/llff_bird 9" "sb samples/bird 14" "b25 $DATA/llff_bird 25"; do
    read -r name scene n <<< "$spec"
    for k in 0 1 2; do
        (
            OMP_NUM_THREADS=1 timeout "$(($(left) - 10))" python3 -m sparself.cli evaluate "$scene" \
                --out "$W/${name}_s$k" $C --first-seed "$k" --inputs "$n" > "$W/${name}_s$k.log" 2>&1
            echo "$name seed $k rc=$? at $(($(date +%s) - t0)) s" > "$W/${name}_s$k.sum"
        ) &
    done
done
wait
cat "$W"/*.sum
find "$W" -name report.html -o -name "*.png" | xargs rm -f
tar czf "$OUT/gpu.tgz" -C "$OUT" work && rm -rf "$W"  # few files come back from a device: one archive
echo "done at $(($(date +%s) - t0)) s"
