#!/usr/bin/env bash
# The SLAM runs this project chooses settings on, and the held-back runs it reports, with one
# SLAM configuration, as a Markdown table.
#
#   lab/scripts/slam_runs.sh selection CONFIG.toml OUT_DIR        # RGB-D: 7-Scenes 0-199, 200-399,
#                                                             # 600-699, TUM fr1_rpy 0-79
#   lab/scripts/slam_runs.sh held-back CONFIG.toml OUT_DIR        # RGB-D: 7-Scenes 400-599,
#                                                             # 700-799, 600-799
#   lab/scripts/slam_runs.sh tum CONFIG.toml OUT_DIR              # RGB-D: TUM fr1_rpy 0-79,
#                                                             # 10-79, 20-79 (selection frames:
#                                                             # for what only TUM data shows)
#   lab/scripts/slam_runs.sh mono-selection CONFIG.toml OUT_DIR   # monocular: 7-Scenes 0-199,
#                                                             # 200-399, 600-699
#   lab/scripts/slam_runs.sh mono-held-back CONFIG.toml OUT_DIR   # monocular: 7-Scenes 700-799,
#                                                             # 600-799
# Choose on a selection set; measure a held-back set once, after choosing.
#
# RGB-D runs: `slam --backend flex --labels none --features {fpfdcnn,orb} --config CONFIG`
# (FPFDCNN from the bundled weights/fpfdcnn); each run's ATE and per-frame RPE (m) and the
# mean ATE per keypoint type. Monocular runs: `slam --backend flex --depth predicted --labels
# sdfcnn --config CONFIG` (bundled FPFDCNN and SDFCNN); each run's Sim(3)-aligned ATE (m), the
# Sim(3) scale and the share of map points within the position tolerance of the sensor's
# surface (Table 11). Two runs at a time: trajectories do not depend on timing; speeds do, so
# do not read them here, nor the last digit of a monocular map's share (its multi-view depth
# reads the live poses of a threaded run: lab/notes/slam-results.md, "Local bundle adjustment"). Needs `cargo build --release` first and the data of ../shared/data
# (README, "Data formats"; scripts/get_data.sh says where to get it): 7scenes_redkitchen_0_799
# and tum_fr1_rpy_head80, or set SEVEN_SCENES / FR1_RPY to other copies in the same layout.
# FPFDCNN=CKPT runs other FPFDCNN weights (a checkpoint folder, as `slam --fpfdcnn`).
set -euo pipefail

usage() {
    echo "usage: $0 selection|held-back|tum|mono-selection|mono-held-back CONFIG.toml OUT_DIR" >&2
    exit 2
}
[ $# -eq 3 ] || usage
set_name=$1
config=$2
out=$3
root=$(cd "$(dirname "$0")/.." && pwd)
slam="$root/target/release/slam"
seven=${SEVEN_SCENES:-$root/../shared/data/7scenes_redkitchen_0_799}
fr1=${FR1_RPY:-$root/../shared/data/tum_fr1_rpy_head80}
weights=()
[ -n "${FPFDCNN:-}" ] && weights=(--fpfdcnn "$FPFDCNN")

# One run a record: name|sequence|first frame|frames.
case $set_name in
selection)
    runs=("s0|$seven|0|200" "s200|$seven|200|200" "s600|$seven|600|100" "fr1|$fr1|0|80")
    ;;
held-back)
    runs=("h400|$seven|400|200" "h700|$seven|700|100" "h600|$seven|600|200")
    ;;
tum)
    runs=("fr1|$fr1|0|80" "fr1_10|$fr1|10|70" "fr1_20|$fr1|20|60")
    ;;
mono-selection)
    runs=("s0|$seven|0|200" "s200|$seven|200|200" "s600|$seven|600|100")
    ;;
mono-held-back)
    runs=("h700|$seven|700|100" "h600|$seven|600|200")
    ;;
*)
    usage
    ;;
esac
[ -x "$slam" ] || { echo "error: $slam not found: run cargo build --release first" >&2; exit 1; }
[ -f "$config" ] || { echo "error: config $config not found" >&2; exit 1; }
for r in "${runs[@]}"; do
    IFS='|' read -r _ seq _ _ <<<"$r"
    [ -f "$seq/rgb.txt" ] || { echo "error: no TUM-layout sequence at $seq (rgb.txt missing)" >&2; exit 1; }
done
mkdir -p "$out"

case $set_name in
mono-*)
    mono=1
    kinds=(mono)
    ;;
*)
    mono=0
    kinds=(fpfdcnn orb)
    ;;
esac

run() { # name sequence first count kind (fpfdcnn, orb: RGB-D; mono: monocular)
    local dir="$out/$1_$5" mode
    if [ "$5" = mono ]; then
        mode=(--depth predicted --labels sdfcnn)
    else
        mode=(--labels none --features "$5")
    fi
    if ! "$slam" --sequence "$2" --first "$3" --max-frames "$4" --backend flex "${mode[@]}" \
        ${weights[@]+"${weights[@]}"} \
        --config "$config" --out "$dir" >"$dir.log" 2>&1; then
        echo "error: run $1 with $5 failed; see $dir.log" >&2
        return 1
    fi
}

failed=0
for features in "${kinds[@]}"; do
    pids=()
    for r in "${runs[@]}"; do
        IFS='|' read -r name seq first count <<<"$r"
        run "$name" "$seq" "$first" "$count" "$features" &
        pids+=($!)
        if [ ${#pids[@]} -eq 2 ]; then
            for p in "${pids[@]}"; do wait "$p" || failed=1; done
            pids=()
        fi
    done
    for p in ${pids[@]+"${pids[@]}"}; do wait "$p" || failed=1; done
done

# The RMSE column of a report.md row ("| ATE Se3-aligned (m) | rmse | mean | ..."); n/a
# when the run wrote no such row.
rmse() {
    local v
    v=$(grep -F -m1 "$2" "$1/report.md" 2>/dev/null | awk -F'|' '{gsub(/ /, "", $3); print $3}') || true
    echo "${v:-n/a}"
}
if [ "$mono" = 1 ]; then
    # "Sim(3) alignment scale: 0.9223" and "Position accuracy: 0.360 of 36450 map points ...".
    field() { grep -m1 "^$2" "$1/report.md" 2>/dev/null | awk -v k="$3" '{print $k}' || true; }
    echo "| run | Sim(3) ATE (m) | Sim(3) scale | map points within tolerance |"
    echo "|---|---|---|---|"
    for r in "${runs[@]}"; do
        IFS='|' read -r name seq first count <<<"$r"
        d="$out/${name}_mono"
        scale=$(field "$d" 'Sim(3) alignment scale:' 4)
        share=$(field "$d" 'Position accuracy:' 3)
        echo "| $name ($(basename "$seq") $first+$count) | $(rmse "$d" 'ATE Sim3-aligned') | ${scale:-n/a} | ${share:-n/a} |"
    done
    exit "$failed"
fi
echo "| run | FPFDCNN ATE / RPE | ORB ATE / RPE |"
echo "|---|---|---|"
for r in "${runs[@]}"; do
    IFS='|' read -r name seq first count <<<"$r"
    row="| $name ($(basename "$seq") $first+$count) |"
    for features in fpfdcnn orb; do
        d="$out/${name}_$features"
        row="$row $(rmse "$d" 'ATE Se3-aligned') / $(rmse "$d" 'RPE translation, 1 frame') |"
    done
    echo "$row"
done
for features in fpfdcnn orb; do
    for r in "${runs[@]}"; do
        IFS='|' read -r name _ _ _ <<<"$r"
        rmse "$out/${name}_$features" 'ATE Se3-aligned'
    done | awk -v f="$features" '
        $1 ~ /^[0-9.]+$/ { s += $1; n++ }
        END { if (n) printf "mean ATE, %s: %.4f m over %d runs\n", f, s / n, n
              else printf "mean ATE, %s: no runs\n", f }'
done
exit "$failed"
