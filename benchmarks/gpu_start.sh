# Sourced by the device scripts (gpu_gsplat.sh, gpu_protocol.sh) after they set DATA, OUT and LIMIT: a
# deadline LIMIT seconds from now (`left` prints the seconds left), the work folder W under OUT, and gsplat's
# CUDA code built once, before any run needs it.
[ -n "$OUT" ] || { echo "$0: give an output folder (OUT)" >&2; exit 2; }  # W=$OUT/work is removed at the end
t0=$(date +%s)
left() { echo $((t0 + LIMIT - $(date +%s))); }
W=$OUT/work
mkdir -p "$W"
export PYTHONPATH=$PWD/src:${PYTHONPATH:-} PYTHONUNBUFFERED=1 MAX_JOBS=16 TORCH_CUDA_ARCH_LIST=9.0
python3 -c "import torch, gsplat; print('torch', torch.__version__, torch.cuda.get_device_name(), 'gsplat', gsplat.__version__)"
timeout "$(left)" python3 -c "from gsplat.cuda._backend import _C; assert _C is not None" > "$W/build.log" 2>&1
echo "gsplat build rc=$? at $(($(date +%s) - t0)) s"
