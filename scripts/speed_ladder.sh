#!/usr/bin/env bash
# The speed/accuracy ladder of RGB-D `slam`: each rung's frames/s, ATE and FPFDCNN's Table 6
# matching accuracy on one TUM-layout sequence, so a user on a slower machine can pick a rung
# (docs/performance.md).
#
#   scripts/speed_ladder.sh [SEQUENCE [CAMERA]]     (default: ../shared/data/tum_fr1_rpy_head80 fr1)
#
# Environment: BIN (default target/release, built by cargo build --release --bins), OUT
# (default runs/speed_ladder), BACKEND (default flex), REPEAT (runs per rung, the fastest
# kept; default 2). Each rung runs alone; run it on an otherwise idle machine.
set -euo pipefail
cd "$(dirname "$0")/.."

SEQ=${1:-../shared/data/tum_fr1_rpy_head80}
CAM=${2:-fr1}
BIN=${BIN:-target/release}
OUT=${OUT:-runs/speed_ladder}
BACKEND=${BACKEND:-flex}
REPEAT=${REPEAT:-2}
mkdir -p "$OUT"
rm -f "$OUT"/matching_*.json

# rung name | slam flags | fpfdcnn_input_scale (empty: ORB keypoints) | other keys of the
# config changed (sed expressions on configs/slam/default.toml)
every_frame='s/^keypoints_every_frame = .*/keypoints_every_frame = true/'
far_keyframes='s/^max_frames_depth_tracked = .*/max_frames_depth_tracked = 20/'
rungs=(
    "FPFDCNN where the depth cannot track + SDFCNN labels (default)|--features fpfdcnn --labels sdfcnn|1.0|"
    "FPFDCNN where the depth cannot track, no labels|--features fpfdcnn --labels none|1.0|"
    "the default, keyframes up to 20 frames apart + labels|--features fpfdcnn --labels sdfcnn|1.0|$far_keyframes"
    "the default, keyframes up to 20 frames apart, no labels|--features fpfdcnn --labels none|1.0|$far_keyframes"
    "the default, FPFDCNN at 0.75 scale + labels|--features fpfdcnn --labels sdfcnn|0.75|"
    "the default, FPFDCNN at 0.5 scale, no labels|--features fpfdcnn --labels none|0.5|"
    "FPFDCNN on every frame + labels (the paper's tracking)|--features fpfdcnn --labels sdfcnn|1.0|$every_frame"
    "FPFDCNN on every frame, no labels|--features fpfdcnn --labels none|1.0|$every_frame"
    "ORB where the depth cannot track + SDFCNN labels|--features orb --labels sdfcnn||"
    "ORB where the depth cannot track, no labels|--features orb --labels none||"
)

field() { python3 -c "import json,sys; d=json.load(open(sys.argv[1])); print(eval(sys.argv[2]))" "$@"; }

table=$OUT/ladder.md
{
    echo "| rung | frames/s | ATE RMSE (m) | Table 6 accuracy (clear) |"
    echo "|---|---|---|---|"
} > "$table"
for k in "${!rungs[@]}"; do
    IFS='|' read -r name flags scale edits <<< "${rungs[$k]}"
    cfg=$OUT/rung_$k.toml
    sed "s/^fpfdcnn_input_scale = .*/fpfdcnn_input_scale = ${scale:-1.0}/; ${edits}" \
        configs/slam/default.toml > "$cfg"
    best_fps=0
    for r in $(seq "$REPEAT"); do
        # shellcheck disable=SC2086
        "$BIN/slam" --sequence "$SEQ" --camera "$CAM" --depth sensor $flags --config "$cfg" \
            --backend "$BACKEND" --out "$OUT/rung_$k" --overwrite > "$OUT/rung_$k.log" 2>&1
        fps=$(field "$OUT/rung_$k/report.json" "d['fps']")
        best_fps=$(python3 -c "print(max($best_fps, $fps))")
    done
    ate=$(field "$OUT/rung_$k/report.json" "'%.4f' % d['ate']['stats']['rmse']")
    # Table 6 accuracy of the rung's keypoints, measured once per keypoint setting.
    matching=$OUT/matching_${scale:-orb}.json
    if [ -n "$scale" ]; then
        [ -f "$matching" ] || "$BIN/eval" matching --sequence "$SEQ" --camera "$CAM" \
            --fpfdcnn-scale "$scale" --backend "$BACKEND" --json "$matching" > /dev/null
        acc=$(field "$matching" "'%.3f' % d['fpfdcnn_range']['clean']['accuracy']")
    else
        [ -f "$matching" ] || "$BIN/eval" matching --sequence "$SEQ" --camera "$CAM" --orb-only \
            --json "$matching" > /dev/null
        acc=$(field "$matching" "'%.3f' % d['orb_bf']['clean']['accuracy']")
    fi
    echo "| $name | $(printf '%.2f' "$best_fps") | $ate | $acc |" | tee -a "$table"
done
echo "wrote $table"
