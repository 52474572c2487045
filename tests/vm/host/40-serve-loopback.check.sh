# shellcheck shell=bash
# What crossline serve recorded from the loopback camera is what feed wrote, and its
# cloud matches `crossline reconstruct` of the recorded frames.
. "$(dirname "$0")/lib.sh"

shopt -s nullglob
recs=("$RESULTS"/out/recordings/*.dump)
((${#recs[@]} == 1)) || fail "expected one recording, found ${#recs[@]}"
rec=${recs[0]}
inspect_to "$DATA/serve-scan.dump" "$RESULTS/fed.inspect.jsonl"
inspect_to "$rec" "$RESULTS/rec.inspect.jsonl"
check_order "$RESULTS/rec.inspect.jsonl" 10
crc_list() { grep '"type":"frame"' "$1" | while read -r l; do echo "$(field bytes <<<"$l") $(field crc32 <<<"$l")"; done; }
mapfile -t fed < <(crc_list "$RESULTS/fed.inspect.jsonl")
mapfile -t got < <(crc_list "$RESULTS/rec.inspect.jsonl")
# The recording starts at the frame the daemon saw first (v4l2loopback may hand a new
# reader its re-initialised last buffer first, see 20-loopback.check.sh: skip it).
first=0
start=-1
for i in "${!fed[@]}"; do [[ ${fed[i]} == "${got[0]}" ]] && start=$i && break; done
if ((start < 0)); then
    first=1
    for i in "${!fed[@]}"; do [[ ${fed[i]} == "${got[1]}" ]] && start=$i && break; done
fi
((start >= 0)) || fail "the recording's first frames are none of the fed frames"
n=$((${#got[@]} - first))
((start + n == ${#fed[@]})) ||
    fail "recorded fed frames $start..$((start + n - 1)), expected through $((${#fed[@]} - 1))"
for ((i = 0; i < n; i++)); do
    [[ ${got[first + i]} == "${fed[start + i]}" ]] ||
        fail "recorded frame $((first + i)) is not fed frame $((start + i))"
done
((n >= 90)) || fail "only $n of ${#fed[@]} fed frames were recorded"
echo "recording: fed frames $start..$((${#fed[@]} - 1)) byte for byte ($n frames)"

# The daemon's cloud against reconstruct of the same recorded frames.
"$CROSSLINE" reconstruct --input "$rec" --camera "$DATA/serve-camera.yml" \
    --out "$RESULTS/reconstruct.ply" 2>"$RESULTS/reconstruct.log" ||
    fail "crossline reconstruct of the recording failed: $(tail -3 "$RESULTS/reconstruct.log")"
"$CROSSLINE" compare "$RESULTS/cloud.ply" --reference "$RESULTS/reconstruct.ply" \
    --align scale --json >"$RESULTS/compare.json" 2>"$RESULTS/compare.log" ||
    fail "crossline compare failed: $(tail -3 "$RESULTS/compare.log")"
python3 - "$RESULTS/compare.json" "$RESULTS/report.json" <<'PY' || fail "the daemon's cloud differs from reconstruct's"
import json, sys
c = json.load(open(sys.argv[1]))
r = json.load(open(sys.argv[2]))
d = c["distances"]
print(f"serve vs reconstruct: median {d['median']:.5f}, p95 {d['p95']:.5f} "
      f"(median depth 1); serve processed {r['frames_processed']} of {r['frames_in']} frames, "
      f"{r['points']} points")
assert r["points"] > 10000, "too few points"
assert d["median"] < 0.01, "median distance over 1 % of the depth"
PY
