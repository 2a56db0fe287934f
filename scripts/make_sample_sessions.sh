#!/usr/bin/env bash
# Regenerates the sample sessions in recordings/ with the app itself: the built-in demo
# (synthetic operator) doing the pick-and-place task, headless and deterministic, once per
# mode. The operator history (eq 6) accumulates across the runs, in this order.
set -euo pipefail
cd "$(dirname "$0")/.."
rm -rf recordings/demo-* recordings/operator_history.json
for mode in DS S manual; do
    .venv/bin/dsteleop run --source demo --mode "$mode" --utensil spoon --seed 0 \
        --record "recordings/demo-$mode-spoon"
done
