#!/usr/bin/env bash
# The built-in demo: every stage that exists so far, at demo size. Usage: scripts/demo.sh OUT_DIR
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-demo_out}
RFIR=".venv/bin/rfir"
mkdir -p "$OUT"

echo "== import: a hand-written CSV of links"
$RFIR import csv docs/examples/links.csv -o "$OUT/imported.h5" --scene example
$RFIR check "$OUT/imported.h5"
$RFIR info "$OUT/imported.h5"
echo "demo finished: artifacts in $OUT/"
