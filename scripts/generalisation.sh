#!/usr/bin/env bash
# Leave-one-scene-out evaluation of SDFCNN: how its depth, and the monocular SLAM built on it,
# hold in a room the network has never seen.
#
# For each real scene X, the bundled SDFCNN's recipe without any frame of X
# (configs/train/generalisation/sdfcnn_without_X.toml) is trained, then scored on X:
#   - depth (eval seg): δ<1.25, REL, RMS; the median scale the prediction needs (sensor depth /
#     prediction, per image), its 10-90 % spread over the images, δ<1.25 after that scale;
#   - monocular SLAM (slam --depth predicted): Sim(3) ATE, the Sim(3) scale (1 = metric) and
#     the share of map points within 5 cm of the sensor's surface;
#   - the camera height anchor: the same monocular run given the camera's height above the
#     floor that the RGB-D run of the same frames measures (slam --camera-height).
# Figures on frames of a training scene are a different row (docs/results.md).
#
#   scripts/generalisation.sh [kitchen|tum ...]        (default: both)
#
# Environment: SHARED (default ../shared/data) holds the real scenes (scripts/get_data.sh);
# OUT (default runs/generalisation) the runs and the table (OUT/<recipe>_table.md, <recipe> the
# configs' name without the scene: sdfcnn_without by default); BACKEND (default flex);
# EPOCHS overrides the recipes' epochs (for a quick trial of the protocol only); BIN names a
# folder of already built binaries (default: build them into target/release); RECIPE the
# configs' common prefix, `RECIPE_<scene>.toml` (default
# configs/train/generalisation/sdfcnn_without), to score another recipe the same way.
# A scene's training resumes where it stopped; a finished one is not trained again.
set -euo pipefail
cd "$(dirname "$0")/.."

SHARED=${SHARED:-../shared/data}
OUT=${OUT:-runs/generalisation}
BACKEND=${BACKEND:-flex}
RECIPE=${RECIPE:-configs/train/generalisation/sdfcnn_without}
scenes=("$@")
[ ${#scenes[@]} -gt 0 ] || scenes=(kitchen tum)

if [ -n "${BIN:-}" ]; then bin=$BIN; else cargo build --release --bins; bin=target/release; fi

# The synthetic rooms of the recipe (generated once).
if [ ! -d datasets/generated/synth_sdfcnn/nyu ]; then
    "$bin/synth" --config configs/synth/sdfcnn_real.toml --out datasets/generated/synth_sdfcnn
fi

# Scene X: its folder, camera, frames scored for depth (FIRST END EVERY) and the segment the
# monocular SLAM runs on (FIRST COUNT).
scene_args() {
    case "$1" in
        kitchen)
            SEQ=$SHARED/7scenes_redkitchen_0_799; CAM=$SEQ/camera.toml
            DEPTH_FRAMES=(0 800 8); SLAM_SEGMENTS=("0 200" "700 100") ;;
        tum)
            SEQ=$SHARED/tum_fr1_rpy_head80; CAM=fr1
            DEPTH_FRAMES=(0 80 1); SLAM_SEGMENTS=("0 80") ;;
        *) echo "unknown scene '$1' (kitchen or tum)" >&2; exit 2 ;;
    esac
}

py_field() { python3 -c "import json,sys; d=json.load(open(sys.argv[1])); print(eval(sys.argv[2]))" "$@"; }

mkdir -p "$OUT"
name=$(basename "$RECIPE")
table=$OUT/${name}_table.md
{
    echo "| scene left out (epoch kept) | frames | depth δ<1.25 | REL | median scale needed (10-90 %) | δ<1.25 after it | segment | mono Sim(3) ATE | scale | map within 5 cm | camera height (RGB-D floor) | with it: scale, map within 5 cm |"
    echo "|---|---|---|---|---|---|---|---|---|---|---|---|"
} > "$table"

for scene in "${scenes[@]}"; do
    scene_args "$scene"
    cfg=${RECIPE}_$scene.toml
    run=$OUT/${name}_$scene
    resume=()
    [ -f "$run/checkpoints/last.json" ] && resume=(--resume)
    epochs=()
    [ -n "${EPOCHS:-}" ] && epochs=(--epochs "$EPOCHS")
    "$bin/train" --config "$cfg" --out "$run" "${resume[@]}" "${epochs[@]}" --quiet

    # The recipe's rule: the epoch with the lowest validation loss (on the scenes it keeps).
    best=$(python3 -c "import csv,sys; r=list(csv.DictReader(open(sys.argv[1]))); print(min(r, key=lambda x: float(x['val_loss']))['epoch'])" "$run/metrics.csv")
    ckpt=$(printf '%s/checkpoints/epoch-%04d' "$run" "$best")
    echo "$scene left out: epoch $best has the lowest validation loss ($ckpt)"

    "$bin/eval" seg --checkpoint "$ckpt" --backend "$BACKEND" --data "$SEQ" --camera "$CAM" \
        --frames "${DEPTH_FRAMES[0]}" "${DEPTH_FRAMES[1]}" --every "${DEPTH_FRAMES[2]}" \
        --json "$OUT/${name}_${scene}_depth.json"
    j=$OUT/${name}_${scene}_depth.json
    depth_cells=$(py_field "$j" "'%.3f | %.3f | %.2f (%.2f-%.2f) | %.3f' % (d['depth']['delta1'], d['depth']['rel'], d['scale']['median'], d['scale']['p10'], d['scale']['p90'], d['scale']['rescaled']['delta1'])")

    for seg in "${SLAM_SEGMENTS[@]}"; do
        read -r first count <<< "$seg"
        mono=$OUT/${name}_${scene}_mono_${first}
        run_slam() {
            "$bin/slam" --sequence "$SEQ" --camera "$CAM" --first "$first" --max-frames "$count" \
                --labels sdfcnn --sdfcnn "$ckpt" --backend "$BACKEND" --overwrite "$@"
        }
        run_slam --depth predicted --out "$mono"
        slam_cells=$(py_field "$mono/report.json" "'%.4f m | %.3f | %.1f %%' % (d['ate']['stats']['rmse'], d['ate']['scale'], 100 * d['map_accuracy']['position_accuracy'])")
        # The camera height anchor, the sensor's map as the tape measure: the camera's height
        # above the floor of the RGB-D map of the same frames, given to the monocular run.
        run_slam --depth sensor --out "$OUT/${name}_${scene}_rgbd_${first}"
        height=$(py_field "$OUT/${name}_${scene}_rgbd_${first}/report.json" "'%.3f' % d['scale']['floor']['camera_height'] if d['scale'].get('floor') else ''")
        anchor_cells="floor not seen | –"
        if [ -n "$height" ]; then
            run_slam --depth predicted --camera-height "$height" --out "${mono}_height"
            anchor_cells="$height m | $(py_field "${mono}_height/report.json" "'%.3f, %.1f %%' % (d['ate']['scale'], 100 * d['map_accuracy']['position_accuracy']) + ('' if d['scale'].get('applied') else ' (floor not seen in the monocular map)')")"
        fi
        echo "| $scene ($best) | ${DEPTH_FRAMES[0]}-$((DEPTH_FRAMES[1] - 1)) every ${DEPTH_FRAMES[2]} | $depth_cells | $first-$((first + count - 1)) | $slam_cells | $anchor_cells |" >> "$table"
    done
done
cat "$table"
