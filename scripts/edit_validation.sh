#!/usr/bin/env bash
# Issue 9's validation: simulate edited scenes with the independent simulator, apply the same edit
# to a fit of the unedited scene with `rfir edit`, compare (stages/edit/validate.py).
# usage: scripts/edit_validation.sh DATA_DIR
#   needs DATA_DIR/classroom (rfir simulate classroom ... --no-photos) with DATA_DIR/rssi/rf_random.h5
#   (docs/rssi.md), and DATA_DIR/lego24 with DATA_DIR/lego24/protocols/scene.h5 (docs/rf-model.md).
set -euo pipefail
D=${1:?data dir}
R=${RFIR:-.venv/bin/rfir}
PY=${PYTHON:-.venv/bin/python}
E=$D/editval
mkdir -p "$E" results
sim() {  # name scene edit [extra args]
  local name=$1 scene=$2 edit=$3; shift 3
  [ -f "$E/$name/measurements.h5" ] || $R "$@" simulate "$scene" "$E/$name" --no-photos --scene-edit "$edit"
}
val() {  # name rf before after [--select S --op O]...
  local name=$1 rf=$2 before=$3 after=$4; shift 4
  OMP_NUM_THREADS=2 $PY -m rfir_stages.edit.validate "$rf" "$before" "$after" "$@" --name "$name" \
    --results "results/edit_$name.json" --plots docs/images/edit_validation --work "$E/work"
}
LEGO=(--set 'simulate.rcs.freqs_hz=[2.4e9]' --set 'simulate.rcs.ranges_m=[3.0]')
sim whiteboard_removed classroom 'whiteboard:delete'
sim desk_row_moved classroom 'desk_0[0369]|chair_0[0369]:translate:0,1,0'
sim back_wall_metal classroom 'wall_back:material:metal'
sim lego_rotate lego 'brick_1[6-9]:rotate:0,0,1,45,0,0,0' "${LEGO[@]}"
[ -f "$E/lego_po/measurements.h5" ] || $R "${LEGO[@]}" simulate lego "$E/lego_po" --no-photos --rcs-backend po
sim lego_po_rotate lego 'brick_1[6-9]:rotate:0,0,1,45,0,0,0' "${LEGO[@]}" --set simulate.rcs_backend=po
for s in global label gaussian; do
  [ -f "$E/lego/rf_$s.h5" ] || $R --seed 0 --set rf_fit.iterations=200 --set rf_fit.sharing=$s rf-fit \
    "$D/lego24/protocols/scene.h5" "$D/lego24/measurements.h5" -o "$E/lego/rf_$s.h5"
  [ -f "$E/lego/rf_po_$s.h5" ] || $R --seed 0 --set rf_fit.iterations=200 --set rf_fit.sharing=$s rf-fit \
    "$D/lego24/protocols/scene.h5" "$E/lego_po/measurements.h5" -o "$E/lego/rf_po_$s.h5"
done
C=$D/classroom/measurements.h5
RF=$D/rssi/rf_random.h5
val classroom_remove_whiteboard "$RF" "$C" "$E/whiteboard_removed/measurements.h5" --select label:whiteboard --op delete
val classroom_move_desk_row "$RF" "$C" "$E/desk_row_moved/measurements.h5" \
  --select 'label:desk_0[0369]' --op translate:0,1,0 --select 'label:chair_0[0369]' --op translate:0,1,0
val classroom_back_wall_metal "$RF" "$C" "$E/back_wall_metal/measurements.h5" --select label:wall_back --op set:gamma_abs=1,a=1
ROT=(--select 'label:brick_1[6-9]' --op rotate:0,0,1,45,0,0,0)
for s in global label gaussian; do
  val lego_rotate_top_sionna_$s "$E/lego/rf_$s.h5" "$D/lego24/measurements.h5" "$E/lego_rotate/measurements.h5" "${ROT[@]}"
  val lego_rotate_top_po_$s "$E/lego/rf_po_$s.h5" "$E/lego_po/measurements.h5" "$E/lego_po_rotate/measurements.h5" "${ROT[@]}"
done
