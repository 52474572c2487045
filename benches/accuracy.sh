#!/usr/bin/env bash
# Accuracy evaluation of `crossline reconstruct` on the built-in scenes, self-calibrated
# and, as the yardstick, with the simulator's true planes (`--true-planes`). Prints per
# scene the median relative depth error, the share of points off by more than 2 % and
# the share of the lit image area covered, and of the part of it where the stripe was
# visible (peak contrast at least 5x the sensor noise), as `self (true planes)`.
# Targets (issue 3): median <= 0.2 % in air and clear water, <= 0.5 % turbid; < 1 %
# of points over 2 %; >= 95 % of the lit area.
#
#   cargo build --release && benches/accuracy.sh [WORKDIR]
#
# Each scene is simulated once as a 300-frame 1920x1080 MJPEG dump, as a camera would
# deliver it (`crossline simulate --scene S --frames 300 --seed 1 --format dump`; the
# turbid one is pipes at --turbidity 1.5 --seed 2) and kept in WORKDIR (default
# target/bench-accuracy). CONFIG=FILE passes a crossline.toml to reconstruct;
# SCENES="room bricks" picks scenes (room bricks pipes turbid).
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${CROSSLINE:-target/release/crossline}
WORK=${1:-target/bench-accuracy}
FRAMES=${FRAMES:-300}
SCENES=${SCENES:-room bricks pipes turbid}
[ -x "$BIN" ] || { echo "build first: cargo build --release" >&2; exit 2; }
CONFIG_ARGS=()
[ -n "${CONFIG:-}" ] && CONFIG_ARGS=(--config "$CONFIG")
mkdir -p "$WORK"

# field FILE KEY [N]: the number after the Nth (default first) "KEY": in a JSON file
# (compare's report).
field() { grep "\"$2\"" "$1" | sed -n "${3:-1}p" | sed 's/.*: *\([-0-9.eE+]*\).*/\1/'; }
# coverage FILE [N]: covered share of the lit (N=1) or visible (N=2) pixels.
coverage() { awk -v c="$(field "$1" covered_lit_pixels "${2:-1}")" -v l="$(field "$1" lit_pixels "${2:-1}")" \
    'BEGIN { printf "%.1f %%", (l > 0 ? 100 * c / l : 0) }'; }
pct() { awk -v x="$1" -v d="$2" 'BEGIN { printf "%.*f %%", d, 100 * x }'; }

printf '%-8s | %-22s | %-20s | %-20s | %-20s | %s\n' scene "median error" "points > 2 %" \
    "lit area covered" "visible lit covered" "seconds (self)"
for scene in $SCENES; do
    case $scene in
        turbid) sim_args=(--scene pipes --turbidity 1.5 --seed 2) ;;
        *) sim_args=(--scene "$scene" --seed 1) ;;
    esac
    sim="$WORK/sim-$scene-$FRAMES"
    if [ ! -f "$sim/frames.dump" ]; then
        "$BIN" simulate "${sim_args[@]}" --frames "$FRAMES" --format dump --out "$sim" \
            2> "$WORK/simulate-$scene.log"
    fi
    for mode in self true; do
        extra=()
        [ "$mode" = true ] && extra=(--true-planes "$sim")
        start=$(date +%s.%N)
        "$BIN" reconstruct --input "$sim/frames.dump" --camera "$sim/camera.yml" \
            "${CONFIG_ARGS[@]}" "${extra[@]}" --out "$WORK/$scene-$mode.ply" \
            --report "$WORK/$scene-$mode-report.json" > "$WORK/$scene-$mode.log" 2>&1
        end=$(date +%s.%N)
        [ "$mode" = self ] && secs=$(awk -v a="$start" -v b="$end" 'BEGIN { printf "%.1f", b - a }')
        "$BIN" compare "$WORK/$scene-$mode.ply" --truth "$sim" --json \
            > "$WORK/$scene-$mode-compare.json" 2>> "$WORK/$scene-$mode.log"
    done
    s="$WORK/$scene-self-compare.json"
    t="$WORK/$scene-true-compare.json"
    printf '%-8s | %-22s | %-20s | %-20s | %-20s | %s\n' "$scene" \
        "$(pct "$(field "$s" median)" 3) ($(pct "$(field "$t" median)" 3))" \
        "$(pct "$(field "$s" outlier_fraction)" 2) ($(pct "$(field "$t" outlier_fraction)" 2))" \
        "$(coverage "$s") ($(coverage "$t"))" \
        "$(coverage "$s" 2) ($(coverage "$t" 2))" \
        "$secs"
done
