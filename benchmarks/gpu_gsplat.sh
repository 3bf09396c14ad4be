#!/bin/bash
# The 3DGS checks on a lent CUDA machine, in one go, each stopped by a shared deadline so that what ran
# comes back: gsplat's CUDA code built once; gsplat against the CPU splatting on the same Gaussians
# (gpu_splat_check.py); the recipe picked on held-back inputs (gsplat_recipe.py); the densification
# protocol with gsplat fitting the 3DGS (`sparself evaluate`, the network trained on the CPU as on the
# 2-core machine, so its views are the CPU runs' own). Everything lands in OUT/gpu.tgz.
#   bash benchmarks/gpu_gsplat.sh DATA OUT [SECONDS]     # DATA holds llff_bird; samples/bird is in the repo
# Without pycolmap on the device (a stock CUDA image), give llff_bird as images/ + poses_bounds.npy (no
# sparse/). On an H200 gsplat's build took 56-67 s, and one capture's protocol (3 seeds, ~60 sequential
# fits) over 7 min: give it a whole call.
set -u
DATA=$1 OUT=$2 LIMIT=${3:-540}
source "$(dirname "$0")/gpu_start.sh"
timeout 60 python3 benchmarks/gpu_splat_check.py > "$W/check.txt" 2>&1; tail -4 "$W/check.txt"
C="--quick --seeds 3 --no-weighted --densify-baselines flow --recon gsplat --device cpu"
for spec in "b9 $DATA/llff_bird 9" "sb samples/bird 14" "b25 $DATA/llff_bird 25"; do
    read -r name scene n <<< "$spec"
    (
        OMP_NUM_THREADS=2 timeout "$(($(left) - 15))" python3 -m sparself.cli evaluate "$scene" --out "$W/$name" \
            $C --inputs "$n" > "$W/$name.log" 2>&1
        echo "rc=$? at $(($(date +%s) - t0)) s" > "$W/$name.sum"
    ) &
done
timeout "$(($(left) - 15))" python3 benchmarks/gsplat_recipe.py --capture "llff_bird=$DATA/llff_bird:9,25" \
    --capture bird=samples/bird:14 --jobs 8 --out "$W/grid" > "$W/grid.log" 2>&1
echo "grid rc=$? at $(($(date +%s) - t0)) s"
wait
cat "$W"/*.sum
tail -n 3 "$W/grid.log" "$W"/b9.log
tar czf "$OUT/gpu.tgz" -C "$OUT" work
echo "done at $(($(date +%s) - t0)) s"
