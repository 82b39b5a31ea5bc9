#!/usr/bin/env bash
# Data sets with hidden effects for `rfir diagnose` (issue 10): for each, a "model" simulated without
# the effect and "measurements" simulated with it, the same links. The effect is not named anywhere
# diagnose looks (it reads only the two files).
# usage: scripts/diagnose_hidden.sh OUT_DIR [quick]
#   quick: only the turntable sets made with the physical-optics solver (seconds each, no Sionna).
set -euo pipefail
OUT=${1:?out dir}
QUICK=${2:-}
R=${RFIR:-.venv/bin/rfir}
mkdir -p "$OUT"
ROOM=(--set 'simulate.rssi.tx_grid=[3,2]' --set 'simulate.rssi.rx_grid=[11,10]')
OBJ=(--set 'simulate.rcs.freqs_hz=[2.4e9]' --set 'simulate.rcs.ranges_m=[3.0]')
WB=(--set simulate.wideband.aspect_step_deg=10.0 --set simulate.wideband.num_freqs=200)
sim() {  # name scene task [--set ...]
  local name=$1 scene=$2 task=$3; shift 3
  [ -f "$OUT/$name/measurements.h5" ] || $R "$@" simulate "$scene" "$OUT/$name" --no-photos --task "$task" >/dev/null
  echo "$name"
}
PO=(--set simulate.rcs_backend=po)
# rcs (lego on the turntable), physical optics: deterministic, no Monte Carlo noise
sim lego_po_clean lego rcs "${OBJ[@]}" "${PO[@]}"
sim lego_po_gain lego rcs "${OBJ[@]}" "${PO[@]}" --set simulate.measurement.gain_offset_db=2.0
sim lego_po_turntable lego rcs "${OBJ[@]}" "${PO[@]}" --set simulate.measurement.aspect_offset_deg=-3.0
sim lego_po_leakage lego rcs "${OBJ[@]}" "${PO[@]}" --set simulate.measurement.leakage_db=-80.0 \
  --set simulate.measurement.leakage_phase_deg=60
sim lego_po_noisy lego rcs "${OBJ[@]}" "${PO[@]}" --set simulate.measurement.noise_db=1.0
# wideband (h-target, physical optics)
sim htarget_clean h-target wideband "${WB[@]}" "${PO[@]}"
sim htarget_ripple h-target wideband "${WB[@]}" "${PO[@]}" --set simulate.measurement.ripple_db=1.5
[ "$QUICK" = quick ] && exit 0
# rssi (classroom): one clean simulation is the model for the measurement-side effects
sim room_clean classroom rssi "${ROOM[@]}"
sim room_gain classroom rssi "${ROOM[@]}" --set simulate.measurement.gain_offset_db=4.0
sim room_noise_floor classroom rssi "${ROOM[@]}" --set simulate.measurement.noise_floor_db=-62.0
sim room_specular_only classroom rssi "${ROOM[@]}" --set simulate.physics.diffuse=false
# receivers also outside the room (1 m beyond the walls): links through the walls
sim room_out_clean classroom rssi "${ROOM[@]}" --set simulate.rssi.rx_margin_m=-1.0
sim room_out_no_transmission classroom rssi "${ROOM[@]}" --set simulate.rssi.rx_margin_m=-1.0 \
  --set simulate.physics.refraction=false
sim room_other_seed classroom rssi "${ROOM[@]}" --set simulate.physics.sionna_seed=8
sim room_saturation classroom rssi "${ROOM[@]}" --set simulate.measurement.saturation_db=-50
sim room_noisy classroom rssi "${ROOM[@]}" --set simulate.measurement.noise_db=2.0
sim room_depth1 classroom rssi "${ROOM[@]}" --set simulate.physics.max_depth=1
# rcs (lego on the turntable)
sim lego_clean lego rcs "${OBJ[@]}"
sim lego_turntable lego rcs "${OBJ[@]}" --set simulate.measurement.aspect_offset_deg=4.0
sim lego_leakage lego rcs "${OBJ[@]}" --set simulate.measurement.leakage_db=-78.0
sim lego_gain lego rcs "${OBJ[@]}" --set simulate.measurement.gain_offset_db=-3.0
sim lego_specular_only lego rcs "${OBJ[@]}" --set simulate.physics.diffuse=false
sim lego_other_seed lego rcs "${OBJ[@]}" --set simulate.physics.sionna_seed=8
sim lego_noisy lego rcs "${OBJ[@]}" --set simulate.measurement.noise_db=2.0
# geometry for the links' crossings (which are shadowed, through how many objects)
[ -f "$OUT/room_geometry.h5" ] || $R mesh-gaussians "$OUT/room_clean/meshes/classroom_gt.ply" -o "$OUT/room_geometry.h5" \
  --spacing 0.8 >/dev/null
