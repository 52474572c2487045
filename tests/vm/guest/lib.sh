# shellcheck shell=sh
# Helpers for the guest tests: `. /vm/lib.sh` at the top of a test.
set -eu

# Prints a message and fails the test.
fail() {
    echo "FAILED: $*" >&2
    exit 1
}

# Waits up to $2 seconds (default 10) for the device node $1.
wait_for_dev() {
    n=0
    while [ ! -e "$1" ]; do
        n=$((n + 1))
        [ $n -le $((${2:-10} * 10)) ] || fail "$1 did not appear"
        sleep 0.1
    done
}

# Runs a command, its output shown, and fails the test if it fails.
run() {
    echo "+ $*"
    "$@" || fail "exit status $?: $*"
}

# Loads kernel module $1 with the parameters that follow, unloading it first if an
# earlier test left it loaded with other parameters.
load_module() {
    m=$1
    shift
    if [ -d "/sys/module/$m" ]; then
        rmmod "$m" || fail "cannot unload $m (still in use?)"
    fi
    echo "+ modprobe $m $*"
    modprobe "$m" "$@" || fail "modprobe $m $* failed"
}
