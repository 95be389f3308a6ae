#!/usr/bin/env bash
# Copy the study's finished runs (those with summary.json) into studies/paper/runs/ as a study keeps them (no
# checkpoints, TorchRL logs or curve images; CSVs and logs xz-compressed; the training records compacted):
#   bash studies/paper/collect.sh <study sweep dir> [destination, default studies/paper/runs]
# (python -m kddrl_trl.devtools.records collect; its docstring says what is kept)
set -euo pipefail
SRC=${1:?usage: collect.sh <study sweep dir> [destination]}
DST=${2:-$(dirname "$0")/runs}
python -m kddrl_trl.devtools.records collect "$SRC" "$DST"
