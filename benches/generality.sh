#!/usr/bin/env bash
# Generality benchmark: self-calibration judged on a fixed draw of random scan
# configurations (scene, camera, lasers, hand path, encoding: `crossline simulate
# --random SEED`), not on the three built-in scenes it was tuned on. Each configuration
# is reconstructed self-calibrated and, as the yardstick, with the simulator's true
# planes (`--true-planes`), and both clouds are measured by `crossline compare --truth`.
#
# Per configuration it prints: seed, kind, the simulator's one-line summary, the
# self-calibrated median and p95 relative depth error, the share of points on wrong
# planes (one frame's one laser whose points' median error is over 2 %), the coverage of
# the visible lit area, the ratios self / true planes of the median and of the coverage,
# the visible-lit coverage of the oracle (below), the seconds of the self-calibrated and
# true-plane reconstructions, and PASS or FAIL (with the bounds missed) on:
#   wrong    points on wrong planes < 0.5 %
#   median   median <= 2 x the true planes' median + 0.01 percentage points
#   coverage visible-lit coverage >= 90 % of the true planes'
#   focal    (with FOCAL_OFF) the recovered focal scale within 0.5 % of 1 / FOCAL_OFF
# The oracle is the self-calibration started from the true planes (`reconstruct
# --start-planes`): every plane still estimated from the crossings and triangulated
# where they determine it, so it shows what the crossings hold whatever a start finds.
# A configuration that misses the median or coverage bound only where the oracle misses
# it too (and the self-calibration gets within the same bound of the oracle, with no
# wrong planes) is WEAK: its geometry does not fix more, and the solver gave what it
# does. Then one summary line: passes, weak ones, the worst wrong-plane share, the
# median of the median ratios, and the failed reconstructions (and simulations). A simulation or
# reconstruction that fails (or times out) is a FAIL row carrying the first line of its
# error; the script goes on.
#
#   cargo build --release && benches/generality.sh
#   FRAMES=100 SEEDS="3 7" benches/generality.sh         # a quick look
#   SEEDS="room bricks pipes" FRAMES=60 benches/generality.sh   # the built-in scenes
#   FOCAL_OFF=0.8 benches/generality.sh                  # also recover a wrong focal length
#   SEEDS=heldout WORK=target/bench-heldout benches/generality.sh   # the held-out draw
#
# Environment:
#   CROSSLINE  the binary (default target/release/crossline)
#   WORK       work folder (default target/bench-generality): sim-SEED/ (the simulation,
#              kept and reused while SEED and FRAMES stay the same; delete it after the
#              simulator changes), run-SEED/ (clouds, reports, compare JSON, logs), and
#              generality.tsv (every row, machine-readable, rewritten by each run; the
#              header names the columns: median, p95, wrong_share (points on wrong
#              planes / evaluated), coverage (visible lit) and true_* are fractions, not
#              per cent; wrong_planes of planes; *_ratio are self / true planes; empty
#              where there is no value)
#   FRAMES     frames per configuration (default 300)
#   SEEDS      the configurations (default: the 24 below; `heldout`: 101-124); an entry
#              that is not a number names a built-in scene (room, bricks, pipes),
#              simulated with --seed 1
#   CONFIG     a crossline.toml for reconstruct
#   EXTRA      extra reconstruct arguments (word-split), for both reconstructions
#   SIM_EXTRA  extra simulate arguments (word-split), e.g. "--readout-frames 0.5" for
#              a rolling shutter (the true planes are then the middle row's)
#   FOCAL_OFF  a factor (e.g. 0.8): the self-calibrated reconstruction gets the camera
#              with fx, fy (and skew) multiplied by it and --estimate-focal; the true-plane
#              one keeps the true camera. The distortion coefficients stay as they are
#              (the lens's), so the factor the solve should find is 1 / FOCAL_OFF with the
#              distortion applied at the corrected radius
#   TIMEOUT    seconds after which a reconstruction counts as failed (default 0: none)
#   DROP_SIMS  1: delete each simulation and the run's PLYs once its row is printed (a
#              300-frame configuration takes 1-2 GB; both draws do not fit a small disk)
#
# How long (2 cores, measured on room and on random seeds 2 and 3): a configuration at
# 300 frames takes 80-140 s the first time: simulate 28-100 s (under water is the
# slowest; cached afterwards), each reconstruction 18-29 s, each compare about 1 s; so
# 45-60 s with its simulation cached. The full 24 take about 40 min the first time and
# about 20 min cached. At FRAMES=100 a configuration takes 15-35 s.
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${CROSSLINE:-target/release/crossline}
WORK=${WORK:-target/bench-generality}
FRAMES=${FRAMES:-300}
# Written once, before any result was seen, and not to be edited after: a different
# draw goes through SEEDS=..., so that figures quoted from the default stay comparable.
SEEDS=${SEEDS:-"1 2 3 4 5 6 7 8 9 10 11 12 13 14 15 16 17 18 19 20 21 22 23 24"}
# The held-out draw (`SEEDS=heldout`): seeds 101-124, fixed on 2026-12-02 before any
# of them was run. Seeds 1-24 have been looked at by every change since they were
# chosen, so they are a tuning set by now; a change is judged on both.
[ "$SEEDS" = heldout ] && SEEDS=$(seq -s ' ' 101 124)
FOCAL_OFF=${FOCAL_OFF:-}
TIMEOUT=${TIMEOUT:-0}
[ -x "$BIN" ] || { echo "build first: cargo build --release (or set CROSSLINE)" >&2; exit 2; }
CONFIG_ARGS=()
[ -n "${CONFIG:-}" ] && CONFIG_ARGS=(--config "$CONFIG")
EXTRA_ARGS=()
# shellcheck disable=SC2206 # EXTRA is a list of arguments, split on purpose
[ -n "${EXTRA:-}" ] && EXTRA_ARGS=($EXTRA)
mkdir -p "$WORK"
TSV="$WORK/generality.tsv"

# first_error LOG: the first line of the error a failed crossline command printed.
first_error() {
    local line
    line=$(grep -m1 'crossline: error:' "$1" || true)
    [ -n "$line" ] || line=$(grep -v '^\s*$' "$1" | tail -n 1 || true)
    echo "${line#crossline: error: }" | tr '\t' ' ' | cut -c1-200
}

# now: seconds since the epoch, with decimals.
now() { date +%s.%N; }

# simulate SEED DIR: simulates configuration SEED into DIR unless DIR already holds
# that simulation; writes DIR/random.json for built-in scenes, as --random does.
simulate() {
    local seed=$1 sim=$2 args kind
    if [[ $seed =~ ^[0-9]+$ ]]; then
        args=(--random "$seed")
    else
        args=(--scene "$seed" --seed 1)
    fi
    args+=(--frames "$FRAMES" --out "$sim")
    [ -n "${SIM_EXTRA:-}" ] && args+=($SIM_EXTRA)
    if [ "$(cat "$sim/.generality-done" 2>/dev/null)" = "${args[*]}" ]; then
        return 0
    fi
    rm -rf "$sim"
    mkdir -p "$sim"
    "$BIN" simulate "${args[@]}" > "$sim/simulate.log" 2>&1 || return 1
    if [[ ! $seed =~ ^[0-9]+$ ]]; then
        case $seed in
            bricks) kind=table ;;
            pipes) kind=underwater ;;
            *) kind=$seed ;;
        esac
        printf '{"seed": 1, "kind": "%s", "summary": "built-in scene %s"}\n' \
            "$kind" "$seed" > "$sim/random.json"
    fi
    echo "${args[*]}" > "$sim/.generality-done"
}

# lasers_args SIM: `--lasers PAIR` when the simulated cross is not the default
# red-green (the colours of the lasers are known hardware, unlike their planes).
lasers_args() {
    python3 - "$1/truth.json" <<'PY'
import json, sys
pair = "-".join(l["name"] for l in json.load(open(sys.argv[1]))["lasers"])
if pair != "red-green":
    print("--lasers", pair)
PY
}

# off_camera IN OUT FACTOR: the OpenCV YAML camera IN with its focal lengths (and skew)
# multiplied by FACTOR. The distortion coefficients stay: they belong to the lens, and
# under water the focal length is what a flat port changes. The true rays are then the
# distortion inverted at the corrected radius, which is what --estimate-focal models.
off_camera() {
    python3 - "$@" <<'PY'
import re, sys
src, dst, f = sys.argv[1], sys.argv[2], float(sys.argv[3])
text = open(src).read()
# camera_matrix: fx, skew, cx, 0, fy, cy, 0, 0, 1.
factors = [f, f, 1, 1, f]
m = re.search(r"camera_matrix:.*?data:\s*\[(.*?)\]", text, re.S)
if m is None:
    sys.exit(f"{src}: no camera_matrix data")
values = [float(v) for v in m.group(1).replace("\n", " ").split(",") if v.strip()]
values = [v * factors[i] if i < len(factors) else v for i, v in enumerate(values)]
text = text[:m.start(1)] + " " + ", ".join(repr(v) for v in values) + " " + text[m.end(1):]
open(dst, "w").write(text)
PY
}

# reconstruct NAME SIM CAMERA [ARGS...]: one reconstruction into $run/NAME.ply, timed,
# and its compare report; sets SECS, and ERR to the error's first line when either
# failed.
reconstruct() {
    local name=$1 sim=$2 camera=$3 start rc=0 limit=()
    shift 3
    [ "$TIMEOUT" != 0 ] && limit=(timeout "$TIMEOUT")
    ERR=
    start=$(now)
    "${limit[@]}" "$BIN" reconstruct --input "$sim" --camera "$camera" "${LASERS_ARGS[@]}" \
        "${CONFIG_ARGS[@]}" "${EXTRA_ARGS[@]}" "$@" --out "$run/$name.ply" \
        --report "$run/$name-report.json" > "$run/$name.log" 2>&1 || rc=$?
    SECS=$(awk -v a="$start" -v b="$(now)" 'BEGIN { printf "%.1f", b - a }')
    if [ "$rc" = 124 ] && [ "$TIMEOUT" != 0 ]; then
        ERR="timed out after $TIMEOUT s"
    elif [ "$rc" != 0 ]; then
        ERR=$(first_error "$run/$name.log")
    elif ! "$BIN" compare "$run/$name.ply" --truth "$sim" --json \
        > "$run/$name-compare.json" 2> "$run/$name-compare.log"; then
        ERR="compare: $(first_error "$run/$name-compare.log")"
    fi
    [ -z "$ERR" ] || rm -f "$run/$name-compare.json"
}

# row SEED SIM RUN SELF_SECS TRUE_SECS SELF_ERR TRUE_ERR [SIM_ERR]: the TSV row of a
# configuration, from random.json and the compare and reconstruct JSON reports.
row() {
    python3 - "$FOCAL_OFF" "$@" <<'PY'
import json, os, sys
focal_off, seed, sim, run, self_secs, true_secs, self_err, true_err = sys.argv[1:9]
sim_err = sys.argv[9] if len(sys.argv) > 9 else ""

def load(path):
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None

info = load(os.path.join(sim, "random.json")) or {}
def truth(name):
    c = load(os.path.join(run, name + "-compare.json"))
    return c["truth"] if c else None
def coverage(t):
    c = t.get("coverage_visible") or t["coverage"]
    return c["fraction"]

s, t = truth("self"), truth("true")
r = {"seed": seed, "kind": info.get("kind", ""), "summary": info.get("summary", ""),
     "self_seconds": self_secs, "true_seconds": true_secs,
     "self_error": self_err, "true_error": true_err, "sim_error": sim_err}
fails = []
if sim_err:
    fails.append("simulate")
elif s:
    r.update(median=s["relative_error"]["median"], p95=s["relative_error"]["p95"],
             wrong_planes=s.get("wrong_planes"), planes=s.get("planes_evaluated"),
             wrong_share=s.get("points_on_wrong_planes_fraction"), coverage=coverage(s))
    if r["wrong_share"] is None or not r["wrong_share"] < 0.005:
        fails.append("wrong")
else:
    fails.append("self failed")
if sim_err:
    pass
elif t:
    r.update(true_median=t["relative_error"]["median"], true_coverage=coverage(t))
else:
    fails.append("true failed")
if s and t:
    r["median_ratio"] = s["relative_error"]["median"] / max(t["relative_error"]["median"], 1e-12)
    r["coverage_ratio"] = coverage(s) / max(coverage(t), 1e-12)
    if not s["relative_error"]["median"] <= 2 * t["relative_error"]["median"] + 1e-4:
        fails.append("median")
    if not r["coverage_ratio"] >= 0.9:
        fails.append("coverage")
# What the crossings hold: the self-calibration started from the true planes. A bound
# that it misses as well is the evidence's, not the solver's: the verdict says WEAK
# (the self-calibration gave what the crossings determine, and no wrong planes).
o = truth("oracle")
if o:
    r.update(oracle_median=o["relative_error"]["median"], oracle_coverage=coverage(o))
weak = []
if s and t and o and r.get("wrong_share") is not None and r["wrong_share"] < 0.005:
    tm, om, sm = t["relative_error"]["median"], o["relative_error"]["median"], s["relative_error"]["median"]
    if "median" in fails and not om <= 2 * tm + 1e-4 and sm <= 2 * om + 1e-4:
        weak.append("median")
    if ("coverage" in fails and not coverage(o) >= 0.9 * coverage(t)
            and coverage(s) >= 0.9 * coverage(o)):
        weak.append("coverage")
if focal_off and not sim_err:
    rep = load(os.path.join(run, "self-report.json")) or {}
    r["focal_true"] = 1 / float(focal_off)
    r["focal_scale"] = rep.get("focal_scale")
    r["focal_scale_std"] = rep.get("focal_scale_std")
    if r["focal_scale"] is None or abs(r["focal_scale"] / r["focal_true"] - 1) > 0.005:
        fails.append("focal")
left = [f for f in fails if f not in weak]
if not fails:
    r["verdict"] = "PASS"
elif not left:
    r["verdict"] = "WEAK(" + ",".join(weak) + ")"
else:
    r["verdict"] = "FAIL(" + ",".join(fails) + ")"
cols = os.environ["COLUMNS_TSV"].split()
print("\t".join("" if r.get(c) is None else str(r[c]).replace("\t", " ") for c in cols))
PY
}

# show LINE: a TSV row as the table's text line (and its errors below it).
show() {
    python3 - "$1" <<'PY'
import os, sys
cols = os.environ["COLUMNS_TSV"].split()
for line in sys.argv[1:]:
    r = dict(zip(cols, line.split("\t")))
    def pct(key, digits=3):
        return f"{100 * float(r[key]):.{digits}f} %" if r.get(key) else "-"
    def ratio(key):
        return f"{float(r[key]):.2f}" if r.get(key) else "-"
    summary = r["summary"] if len(r["summary"]) <= 34 else r["summary"][:33] + "…"
    text = (f"{r['seed']:>6} {r['kind']:<10} {summary:<34} {pct('median'):>9} {pct('p95'):>9} "
            f"{pct('wrong_share', 2):>8} {pct('coverage', 1):>7} {ratio('median_ratio'):>6} "
            f"{ratio('coverage_ratio'):>6} {pct('oracle_coverage', 1):>7} "
            f"{r['self_seconds']:>6} {r['true_seconds']:>6}")
    if "focal_true" in cols:
        f = f"{float(r['focal_scale']):.4f}" if r.get("focal_scale") else "-"
        text += f" {f:>7}/{float(r['focal_true']):.4f}"
    text += f"  {r['verdict']}"
    for key in ("sim_error", "self_error", "true_error"):
        if r.get(key):
            text += f"\n{'':>6} {key.split('_')[0]}: {r[key]}"
    print(text)
PY
}

# summary TSV: the closing line over every row of the TSV file.
summary() {
    python3 - "$1" <<'PY'
import os, statistics, sys
cols = os.environ["COLUMNS_TSV"].split()
rows = [dict(zip(cols, l.rstrip("\n").split("\t"))) for l in open(sys.argv[1])][1:]
passes = sum(r["verdict"] == "PASS" for r in rows)
weak = sum(r["verdict"].startswith("WEAK") for r in rows)
wrong = [float(r["wrong_share"]) for r in rows if r.get("wrong_share")]
ratios = [float(r["median_ratio"]) for r in rows if r.get("median_ratio")]
failed_self = sum(bool(r["self_error"]) for r in rows)
failed_true = sum(bool(r["true_error"]) for r in rows)
failed_sim = sum(bool(r["sim_error"]) for r in rows)
print(f"{passes} / {len(rows)} pass, {weak} weak (the crossings fix no more); worst wrong-plane share "
      + (f"{100 * max(wrong):.2f} %" if wrong else "-")
      + "; median of the median ratios "
      + (f"{statistics.median(ratios):.2f}" if ratios else "-")
      + f"; failed reconstructions: {failed_self} self-calibrated, {failed_true} true planes"
      + (f"; failed simulations: {failed_sim}" if failed_sim else ""))
PY
}

COLUMNS_TSV="seed kind summary median p95 wrong_share wrong_planes planes coverage \
true_median true_coverage median_ratio coverage_ratio oracle_median oracle_coverage \
self_seconds true_seconds"
[ -n "$FOCAL_OFF" ] && COLUMNS_TSV+=" focal_scale focal_scale_std focal_true"
COLUMNS_TSV+=" verdict self_error true_error sim_error"
export COLUMNS_TSV
echo "$COLUMNS_TSV" | tr ' ' '\t' > "$TSV"

printf '%6s %-10s %-34s %9s %9s %8s %7s %6s %6s %7s %6s %6s' seed kind summary median p95 \
    wrong cover "med×" "cov×" "oracle" "s self" "s true"
[ -n "$FOCAL_OFF" ] && printf ' %15s' "focal found/true"
printf '  %s\n' verdict
for seed in $SEEDS; do
    sim="$WORK/sim-$seed"
    run="$WORK/run-$seed"
    rm -rf "$run"
    mkdir -p "$run"
    if ! simulate "$seed" "$sim"; then
        line=$(row "$seed" "$sim" "$run" "" "" "" "" "$(first_error "$sim/simulate.log")")
        echo "$line" >> "$TSV"
        show "$line"
        continue
    fi
    LASERS_ARGS=()
    read -r -a LASERS_ARGS < <(lasers_args "$sim" 2> "$run/lasers.log") || true
    self_args=()
    camera="$sim/camera.yml"
    if [ -n "$FOCAL_OFF" ]; then
        camera="$run/camera-off.yml"
        off_camera "$sim/camera.yml" "$camera" "$FOCAL_OFF"
        self_args=(--estimate-focal)
    fi
    reconstruct self "$sim" "$camera" "${self_args[@]}"
    self_secs=$SECS self_err=$ERR
    reconstruct oracle "$sim" "$camera" "${self_args[@]}" --start-planes "$sim"
    reconstruct true "$sim" "$sim/camera.yml" --true-planes "$sim"
    line=$(row "$seed" "$sim" "$run" "$self_secs" "$SECS" "$self_err" "$ERR")
    echo "$line" >> "$TSV"
    show "$line"
    # The run's clouds are the big part after the simulation; keep the reports.
    if [ "${DROP_SIMS:-0}" = 1 ]; then rm -rf "$sim" "$run"/*.ply; fi
done
summary "$TSV"
echo "rows: $TSV"
