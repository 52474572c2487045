# shellcheck shell=bash
# The vivid recordings: 30 whole frames each, in order, of the negotiated size,
# and decodable the way reconstruct decodes them.
. "$(dirname "$0")/lib.sh"

for fmt in yuyv mjpg; do
    dump=$RESULTS/vivid-$fmt.dump
    out=$RESULTS/vivid-$fmt.inspect.jsonl
    inspect_to "$dump" "$out"
    header=$(grep -m1 '"type":"header"' "$out")
    end=$(grep '"type":"end"' "$out")
    echo "$fmt: $header"
    echo "$fmt: $end"
    fourcc=$(field fourcc <<<"$header")
    [[ $(field width <<<"$header")x$(field height <<<"$header") == 640x360 ]] ||
        fail "$dump: negotiated $(field width <<<"$header")x$(field height <<<"$header"), asked for 640x360"
    [[ $(field interval_num <<<"$header")/$(field interval_den <<<"$header") == 1/30 ]] ||
        fail "$dump: frame interval $(field interval_num <<<"$header")/$(field interval_den <<<"$header") s, asked for 30 fps (vivid offers it)"
    [[ $(field frames <<<"$end") == 30 ]] || fail "$dump: $(field frames <<<"$end") frames, asked for 30"
    case $fmt in
    yuyv) [[ $fourcc == YUYV ]] || fail "$dump: fourcc $fourcc, asked for YUYV (which vivid offers)" ;;
    mjpg) [[ $fourcc != MJPG ]] || fail "$dump: fourcc MJPG, which vivid does not offer" ;;
    esac
    if [[ $fourcc == YUYV ]]; then
        bpl=$(field bytes_per_line <<<"$header")
        ((bpl >= 1280)) || fail "$dump: $bpl bytes per line for 640 YUYV pixels"
        sizes=$(grep '"type":"frame"' "$out" | field bytes | sort -u)
        [[ $sizes == $((bpl * 360)) ]] || fail "$dump: payload sizes $sizes, expected $((bpl * 360))"
    fi
    check_order "$out"
    ts=$(grep '"type":"frame"' "$out" | field timestamp_nanos | head -n1)
    ((ts > 0)) || fail "$dump: first timestamp $ts"
    for n in 0 29; do
        decoded=$("$CROSSLINE" inspect "$dump" --decode $n --png "$RESULTS/vivid-$fmt-$n.png" | grep '"type":"decode"') ||
            fail "$dump: frame $n does not decode"
        [[ $(field width <<<"$decoded")x$(field height <<<"$decoded") == 640x360 ]] ||
            fail "$dump: frame $n decodes to $(field width <<<"$decoded")x$(field height <<<"$decoded")"
    done
done
