#!/usr/bin/env bash
# The simulator on a CUDA GPU (docs/benchmarks.md, "On a GPU"; docs/validation-rest-3d.md, "Boundary particles"):
#   1. the CUDA tests (tests/test_cuda.py, the rheology laws on cuda): the GPU gives the CPU's forces, gradients and
#      sensitivities;
#   2. ms per step forward and forward+backward on the GPU, next to the eager step on the CPU in the same process;
#   3. the 3-D rod's buoyancy at rest with boundary particles on 2.5 mm cells (to check against the CPU's run of the
#      same command) and on 1.25 mm cells (the convergence the CPU could not afford), the latter cut off
#      DEADLINE seconds after the script's start.
#
#   scripts/gpu_check.sh OUT_DIR [DEADLINE]
#
# Runs from the repository root with the diffstir package on PYTHONPATH (no install needed); writes each part's
# output to OUT_DIR.
source "$(dirname "$0")/gpu_run.sh"
lap "tests"
python3 -m pytest -q -p no:cacheprovider tests/test_cuda.py 2>&1 | tee "$out/tests.txt"
python3 -m pytest -q -p no:cacheprovider tests/test_rheology_laws.py -k cuda 2>&1 | tee -a "$out/tests.txt"
lap "benchmark"
python3 scripts/benchmark_simulator.py --device cuda --scenes paper3d slice2d --variants eager walls cpu \
    --repeats 2 2>&1 | tee "$out/benchmark.txt"
lap "rest, 2.5 mm"
python3 scripts/rest_pressure_3d.py --dx 0.0025 --hold 0.05 --wall-pressure --device cuda 2>&1 \
    | tee "$out/rest_2.5mm.txt"
lap "rest, 1.25 mm"
timeout $(( deadline - $(date +%s) + start )) python3 scripts/rest_pressure_3d.py --dx 0.00125 --hold 0.05 --wall-pressure --device cuda \
    2>&1 | tee "$out/rest_1.25mm.txt"
lap "done"
