# What record captured from v4l2loopback is what feed wrote: same stream, and
# consecutive payloads identical to consecutive fed ones (the feeder loops, so the
# recording may start at any fed frame and wrap around).
. "$(dirname "$0")/lib.sh"

inspect_to "$DATA/bricks.dump" "$RESULTS/fed.inspect.jsonl"
inspect_to "$RESULTS/loop.dump" "$RESULTS/loop.inspect.jsonl"
fed_header=$(grep -m1 '"type":"header"' "$RESULTS/fed.inspect.jsonl")
rec_header=$(grep -m1 '"type":"header"' "$RESULTS/loop.inspect.jsonl")
echo "fed:      $fed_header"
echo "recorded: $rec_header"
for k in fourcc width height; do
    [[ $(field $k <<<"$fed_header") == $(field $k <<<"$rec_header") ]] ||
        fail "$k: fed $(field $k <<<"$fed_header"), recorded $(field $k <<<"$rec_header")"
done
check_order "$RESULTS/loop.inspect.jsonl"

# One "bytes crc32" line per frame.
mapfile -t fed < <(grep '"type":"frame"' "$RESULTS/fed.inspect.jsonl" | while read -r l; do
    echo "$(field bytes <<<"$l") $(field crc32 <<<"$l")"
done)
mapfile -t rec < <(grep '"type":"frame"' "$RESULTS/loop.inspect.jsonl" | while read -r l; do
    echo "$(field bytes <<<"$l") $(field crc32 <<<"$l")"
done)
((${#rec[@]} == 20)) || fail "recorded ${#rec[@]} frames, asked for 20"
start=-1
for i in "${!fed[@]}"; do
    [[ ${fed[i]} == "${rec[0]}" ]] && start=$i && break
done
((start >= 0)) || fail "the first recorded frame (bytes, crc32: ${rec[0]}) is none of the fed frames"
for i in "${!rec[@]}"; do
    want=${fed[$(((start + i) % ${#fed[@]}))]}
    [[ ${rec[i]} == "$want" ]] ||
        fail "recorded frame $i (bytes, crc32: ${rec[i]}) is not fed frame $(((start + i) % ${#fed[@]})) ($want)"
done
echo "20 recorded frames equal fed frames $start.. (wrapping at ${#fed[@]})"
