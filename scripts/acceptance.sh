#!/usr/bin/env bash
# The whole acceptance suite (docs/acceptance.md): every command on its default configuration, including the
# default fits, the behaviour and mixing experiments, the diagnosis and a pairs shard that CI's budget leaves out.
#   scripts/acceptance.sh            # all of tests/acceptance, two processes
#   scripts/acceptance.sh -k fit     # any pytest selection
# Each command's start, wall time [s], exit status and last output line are appended to outputs/acceptance-timing.log
# (DIFFSTIR_ACCEPTANCE_LOG to put it elsewhere).
set -euo pipefail
cd "$(dirname "$0")/.."
mkdir -p outputs
export DIFFSTIR_ACCEPTANCE_LOG="${DIFFSTIR_ACCEPTANCE_LOG:-$PWD/outputs/acceptance-timing.log}"
DIFFSTIR_ACCEPTANCE=full exec python3 -m pytest -q -n 2 --dist load -m acceptance tests/acceptance --durations=0 "$@"
