#!/usr/bin/env bash
# RCS under the paper's protocol and harder ones, plus the ablations, each beside the baselines.
# Usage: scripts/rcs_protocols.sh DATA_DIR NAME [ITERATIONS] [PROTOCOLS...]
#   DATA_DIR: output of `rfir simulate SCENE DATA_DIR` (measurements.h5 and meshes/*_gt.ply)
#   NAME:     prefix of the results files, results/NAME_<protocol>.json
#   PROTOCOLS (default: data every-10 sector:45:135 ablation-path-loss ablation-phase); "range:3"
#   needs data at several ranges.
# Each protocol: rf-fit on its training rows, predict rcs on its test rows, results JSON + plots
# under DATA_DIR/protocols/. Wall time per run is in the JSON (fit and predict).
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=$1
NAME=$2
ITER=${3:-200}
shift $(( $# < 3 ? $# : 3 ))
PROTOCOLS=("$@")
[ ${#PROTOCOLS[@]} -eq 0 ] && PROTOCOLS=(data every-10 sector:45:135 ablation-path-loss ablation-phase)
RFIR=".venv/bin/rfir"
OUT="$DATA/protocols"
mkdir -p "$OUT" results
MESH=$(ls "$DATA"/meshes/*_gt.ply | head -1)
[ -f "$OUT/scene.h5" ] || $RFIR mesh-gaussians "$MESH" -o "$OUT/scene.h5" --spacing 0.03
for p in "${PROTOCOLS[@]}"; do
    tag=${p//:/_}
    set_args=()
    split=$p
    case $p in
        ablation-path-loss) set_args=(--set rf_fit.path_loss=false); split=data ;;
        ablation-phase) set_args=(--set rf_fit.phase=false); split=data ;;
    esac
    echo "== $NAME: $p"
    $RFIR "${set_args[@]}" rf-fit "$OUT/scene.h5" "$DATA/measurements.h5" -o "$OUT/rf_$tag.h5" \
        --split "$split" --iterations "$ITER"
    $RFIR predict rcs "$OUT/rf_$tag.h5" -o "$OUT/pred_$tag.h5" --measurements "$DATA/measurements.h5" \
        --plots "$OUT/plots_$tag" --results "results/${NAME}_$tag.json"
done
