#!/usr/bin/env bash
# The 3-D MPM's own error on a CUDA GPU (docs/accuracy-slice.md, The 3-D MPM's own error): the drag of the rod stirring
# the paper's cup (rig paper_e25, 1 Pa·s, 0.1 m/s) at 1 cm (conf/sim/paper3d.yaml), 5 mm (conf/sim/fine3d.yaml)
# and 2.5 mm cells (fine3d's numerics), against the finite-element cup's 0.328 N (docs/data/slice_error.json).
# The 2.5 mm run, the dearest, comes last and is cut off DEADLINE seconds after the script's start.
#
#   scripts/mpm3d_error_gpu.sh OUT_DIR [DEADLINE]
#
# Runs from the repository root with the diffstir package on PYTHONPATH (no install needed; scripts/slice_error.py
# imports scikit-fem); writes each run's JSON to OUT_DIR.
source "$(dirname "$0")/gpu_run.sh"
lap "1 cm"
python3 scripts/slice_error.py --mpm paper3d --duration 3 --set device=cuda 2>&1 | tee "$out/mpm3d_10mm.json"
lap "5 mm"
python3 scripts/slice_error.py --mpm fine3d --duration 3 --set device=cuda 2>&1 | tee "$out/mpm3d_5mm.json"
lap "2.5 mm"
timeout $(( deadline - $(date +%s) + start )) python3 scripts/slice_error.py --mpm fine3d --duration 1.5 \
    --set dx=0.0025 device=cuda 2>&1 | tee "$out/mpm3d_2.5mm.json"
lap "done"
