#!/usr/bin/env bash
# The built-in demo: every stage that exists so far, on the lego at demo size (configs/recipes/demo.toml).
# Usage: scripts/demo.sh OUT_DIR   (about 4 minutes on an idle 2-core CPU)
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-demo_out}
RFIR=".venv/bin/rfir"
rm -rf "$OUT"
mkdir -p "$OUT"

echo "== 1/5 simulate: photos, ground-truth meshes and monostatic RCS of the lego (Sionna RT, Mitsuba)"
$RFIR --recipe demo simulate lego "$OUT/lego"
$RFIR check "$OUT/lego/measurements.h5" "$OUT/lego/cameras.h5"

echo "== 2/5 calibrate: camera poses from the photos (pycolmap SfM), aligned to metres"
$RFIR calibrate "$OUT/lego/images" -o "$OUT/calib.h5" --poses "$OUT/lego/cameras.h5" \
    --intrinsics-from "$OUT/lego/cameras.h5"

echo "== 3/5 geom: 3D Gaussians with normals trained from the calibrated photos (compared with the true mesh)"
$RFIR geom "$OUT/calib.h5" -o "$OUT/scene.h5"

echo "== 4/5 rf-fit: radio materials (eps_r, sigma, slab thickness, S; per segment of the Gaussians or one for the"
echo "   object, chosen by validation) fitted to the even aspects, then the fitted materials"
$RFIR rf-fit "$OUT/scene.h5" "$OUT/lego/measurements.h5" -o "$OUT/rf.h5"
$RFIR info "$OUT/rf.h5" | sed -n '/fitted materials/,$p'

echo "== 5/5 predict rcs: the odd aspects, beside the nearest-aspect and interpolation baselines"
$RFIR predict rcs "$OUT/rf.h5" -o "$OUT/predictions.h5" --measurements "$OUT/lego/measurements.h5" \
    --plots "$OUT/plots" --results "$OUT/results.json"

echo "demo finished: artifacts in $OUT/, plots in $OUT/plots/, metrics in $OUT/results.json"
