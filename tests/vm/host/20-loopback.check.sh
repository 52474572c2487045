# shellcheck shell=bash
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

# One "bytes crc32 offset sequence" line per frame.
frame_table() {
    grep '"type":"frame"' "$1" | while read -r l; do
        echo "$(field bytes <<<"$l") $(field crc32 <<<"$l") $(field offset <<<"$l") $(field sequence <<<"$l")"
    done
}
mapfile -t fed < <(frame_table "$RESULTS/fed.inspect.jsonl")
mapfile -t rec < <(frame_table "$RESULTS/loop.inspect.jsonl")
((${#rec[@]} == 20)) || fail "recorded ${#rec[@]} frames, asked for 20"
payload_id() { # "bytes crc32" of a table line
    local bytes crc
    read -r bytes crc _ <<<"$1"
    echo "$bytes $crc"
}
position_in_fed() { # index of the fed frame with this payload, or -1
    local i
    for i in "${!fed[@]}"; do
        [[ $(payload_id "${fed[i]}") == "$1" ]] && echo "$i" && return
    done
    echo -1
}

# v4l2loopback 0.12.7 resets every buffer header when the capture side asks for
# buffers (init_buffers() in vidioc_reqbufs), and a new reader's first DQBUF returns
# the newest written buffer at once. Unless the writer queues a frame in between,
# that first buffer holds the last fed frame but says sequence 0 and bytesused =
# sizeimage (the frame plus stale buffer bytes). That one frame is the driver's, not
# crossline's: it is accepted only at index 0, with sequence 0, when its payload
# starts with exactly the fed frame before the next recorded one.
first=0
start=$(position_in_fed "$(payload_id "${rec[0]}")")
if ((start < 0)); then
    read -r bytes _ offset sequence <<<"${rec[0]}"
    next=$(position_in_fed "$(payload_id "${rec[1]}")")
    ((sequence == 0 && next >= 0)) ||
        fail "the first recorded frame (bytes crc32 offset sequence: ${rec[0]}) is none of the fed frames"
    prev=$(((next + ${#fed[@]} - 1) % ${#fed[@]}))
    read -r fed_bytes _ fed_offset _ <<<"${fed[prev]}"
    ((bytes >= fed_bytes)) || fail "recorded frame 0 (${rec[0]}) is shorter than fed frame $prev"
    cmp -s <(tail -c +$((offset + 25)) "$RESULTS/loop.dump" | head -c "$fed_bytes") \
        <(tail -c +$((fed_offset + 25)) "$DATA/bricks.dump" | head -c "$fed_bytes") ||
        fail "recorded frame 0 (${rec[0]}) neither is nor starts with fed frame $prev"
    echo "recorded frame 0 is v4l2loopback's re-initialised buffer: fed frame $prev plus $((bytes - fed_bytes)) stale bytes"
    first=1
    start=$next
fi
for ((i = first; i < ${#rec[@]}; i++)); do
    k=$(((start + i - first) % ${#fed[@]}))
    [[ $(payload_id "${rec[i]}") == "$(payload_id "${fed[k]}")" ]] ||
        fail "recorded frame $i (bytes crc32 offset sequence: ${rec[i]}) is not fed frame $k (${fed[k]})"
done
echo "recorded frames $first..19 equal fed frames $start.. (wrapping at ${#fed[@]})"
