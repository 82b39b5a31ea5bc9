#!/usr/bin/env bash
# Edits checked against the independent simulator (docs/guide/edit.md): simulate the edited scenes, apply the
# same edit with `rfir edit` to a fit of the unedited scene, compare (stages/edit/validate.py).
# usage: scripts/edit_validation.sh DATA_DIR
#   needs DATA_DIR/classroom/measurements.h5 (rfir simulate classroom DATA_DIR/classroom --no-photos)
#   and DATA_DIR/classroom/meshes/classroom_gt.ply; everything else is made under DATA_DIR/editval.
#   Results: results/edit_<name>.json; pictures: docs/images/edit_validation/.
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
  OMP_NUM_THREADS=2 $PY scripts/edit_validate.py "$rf" "$before" "$after" "$@" --name "$name" \
    --results "results/edit_$name.json" --plots docs/images/edit_validation --work "$E/work"
}

# The classroom: the room model (docs/physics.md) fitted on the unedited scene.
C=$D/classroom/measurements.h5
[ -f "$E/classroom/scene.h5" ] || $R mesh-gaussians "$D/classroom/meshes/classroom_gt.ply" \
  -o "$E/classroom/scene.h5" --spacing 0.8 --object-cells 12 --rectangles --drop-contact-faces      # the room recipe (docs/guide/photos-to-scene.md)
[ -f "$E/classroom/rf.h5" ] || $R --seed 0 rf-fit "$E/classroom/scene.h5" "$C" -o "$E/classroom/rf.h5"
sim whiteboard_removed classroom 'whiteboard:delete'
sim desk_row_moved classroom 'desk_0[0369]|chair_0[0369]:translate:0,1,0'
sim back_wall_metal classroom 'wall_back:material:metal'
RF=$E/classroom/rf.h5
val classroom_remove_whiteboard "$RF" "$C" "$E/whiteboard_removed/measurements.h5" --select label:whiteboard --op delete
val classroom_move_desk_row "$RF" "$C" "$E/desk_row_moved/measurements.h5" \
  --select 'label:desk_0[0369]' --op translate:0,1,0 --select 'label:chair_0[0369]' --op translate:0,1,0
val classroom_back_wall_metal "$RF" "$C" "$E/back_wall_metal/measurements.h5" --select label:wall_back --op material:metal

# The lego at 2.4 GHz, 3 m: the top four bricks rotated 45 degrees, Sionna and physical-optics data,
# the physical model with one material for the object and with a material per brick.
LEGO=(--set 'simulate.rcs.freqs_hz=[2.4e9]' --set 'simulate.rcs.ranges_m=[3.0]')
ROT_SIM='brick_1[6-9]:rotate:0,0,1,45,0,0,0'
ROT=(--select 'label:brick_1[6-9]' --op rotate:0,0,1,45,0,0,0)
for backend in sionna po; do
  [ -f "$E/lego_$backend/measurements.h5" ] || $R "${LEGO[@]}" simulate lego "$E/lego_$backend" --no-photos \
    --task rcs --rcs-backend $backend
  [ -f "$E/lego_${backend}_rotate/measurements.h5" ] || $R "${LEGO[@]}" simulate lego "$E/lego_${backend}_rotate" \
    --no-photos --task rcs --rcs-backend $backend --scene-edit "$ROT_SIM"
done
[ -f "$E/lego/scene.h5" ] || $R mesh-gaussians "$E/lego_sionna/meshes/lego_gt.ply" -o "$E/lego/scene.h5" --spacing 0.03
for backend in sionna po; do
  for s in global label; do
    rf=$E/lego/rf_${backend}_$s.h5
    [ -f "$rf" ] || $R --seed 0 --set rf_fit.physical.sharing=$s rf-fit "$E/lego/scene.h5" \
      "$E/lego_$backend/measurements.h5" -o "$rf"
    val lego_rotate_top_${backend}_$s "$rf" "$E/lego_$backend/measurements.h5" \
      "$E/lego_${backend}_rotate/measurements.h5" "${ROT[@]}"
  done
done
