# shellcheck shell=bash
# Helpers for the host-side checks (tests/vm/host/NAME.check.sh): `. "$(dirname "$0")/lib.sh"`.
# A check gets RESULTS (the guest test's folder), DATA and CROSSLINE; it fails by
# exiting non-zero, saying why.

fail() {
    echo "FAILED: $*" >&2
    exit 1
}

# The value of KEY in the JSON line on standard input (numbers and strings without
# quotes or escapes, which is all `crossline inspect` prints for these keys).
field() {
    sed -n "s/.*\"$1\":\(\"[^\"]*\"\|[^,}]*\).*/\1/p" | tr -d '"'
}

# `crossline inspect DUMP --frames` into OUT; fails unless the dump is clean.
inspect_to() {
    "$CROSSLINE" inspect "$1" --frames >"$2" || fail "crossline inspect $1: damaged or unreadable (see $2)"
}

# Checks the frame lines of an inspect output: sequence numbers strictly increasing,
# timestamps non-decreasing, no gap between frames above $2 seconds (default 2).
check_order() {
    awk -v max_gap_s="${2:-2}" '
        function f(k) {
            if (!match($0, "\"" k "\":[^,}]*")) return ""
            v = substr($0, RSTART + length(k) + 3, RLENGTH - length(k) - 3)
            gsub(/"/, "", v)
            return v
        }
        /"type":"frame"/ {
            seq = f("sequence") + 0; ts = f("timestamp_nanos") + 0
            if (n > 0) {
                if (seq <= last_seq) { print "frame " n ": sequence " seq " after " last_seq; bad = 1 }
                if (ts < last_ts) { print "frame " n ": timestamp " ts " before " last_ts; bad = 1 }
                if (ts - last_ts > max_gap_s * 1e9) { print "frame " n ": " (ts - last_ts) / 1e9 " s after the previous one"; bad = 1 }
            }
            last_seq = seq; last_ts = ts; n++
        }
        END { exit bad }
    ' "$1" || fail "frame order in $1"
}
