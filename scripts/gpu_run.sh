# Sourced by the GPU scripts (scripts/gpu_check.sh, scripts/mpm3d_error_gpu.sh) with their OUT_DIR [DEADLINE]
# arguments: puts the diffstir package of the repository root on PYTHONPATH (no install needed), a per-script
# kernel cache in DIFFSTIR_CACHE_DIR, and `out`, `deadline` [s, default 1200], `start` and `lap LABEL` (seconds
# since the start) in the caller; writes the GPU, Python and torch versions to OUT_DIR/gpu.txt.
set -uo pipefail
out=${1:?usage: $0 OUT_DIR [DEADLINE]}
deadline=${2:-1200}
mkdir -p "$out"
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1 \
    DIFFSTIR_CACHE_DIR="${TMPDIR:-/tmp}/diffstir-$(basename "$0" .sh)"
start=$(date +%s)
lap() { echo "== $1: $(( $(date +%s) - start )) s since the start"; }

nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv | tee "$out/gpu.txt"
python3 -c "import torch, sys; print('python', sys.version.split()[0], 'torch', torch.__version__)" | tee -a "$out/gpu.txt"
