#!/usr/bin/env bash
# The solve's out-of-core and resume claims on a large grid, shown with the real binary.
#
#   benches/solve_large.sh [N] [MEM] [DIR]      (defaults: 512 256MiB /tmp/harmap-solve-large)
#   environment: BIG (the large budget, 8GiB), EVERY (checkpoint interval, 5s),
#                KILLS (seconds after a process's first checkpoint to kill it, "3 11 20")
#
# 1. reference: `harmap bench solve --n N --mem MEM --keep` (the standard ball, multigrid,
#    rtol 1e-6, within MEM; prints time, cycles and peak RSS) leaves the solved run;
# 2. budget:    the same labels solved with a budget large enough to keep every level in
#    memory (--mem BIG, default 8GiB); phi must be the same bytes as the run within MEM;
# 3. resume:    the same labels solved with checkpoints every EVERY, killed with SIGKILL at
#    three moments (each restart with --resume), then resumed to the end; phi must be the
#    same bytes as the uninterrupted reference.
#
# Byte equality is checked on the stored chunks (`cmp` of every file under phi/), which
# is stricter than the 1e-6 the issue asks for: the solver is deterministic across
# budgets, thread counts and resumes, and the chunk encoding is too.
# Needs about 6 * 8 * N^3 bytes of disk in DIR (27 GB at N = 512).
set -euo pipefail

N=${1:-512}
MEM=${2:-256MiB}
DIR=${3:-/tmp/harmap-solve-large}
BIG=${BIG:-8GiB}
EVERY=${EVERY:-5s}
KILLS=${KILLS:-3 11 20}
cd "$(dirname "$0")/.."
cargo build --release --quiet
H=$PWD/target/release/harmap

rm -rf "$DIR"
mkdir -p "$DIR"
REF=$DIR/bench-solve-$N.harmap

echo "== reference: N=$N --mem $MEM"
"$H" bench solve --n "$N" --mem "$MEM" --dir "$DIR" --keep

# A fresh copy of the labels: the run without its phi.
fresh() {
    rm -rf "$1"
    mkdir -p "$1"
    (cd "$REF" && find . -path ./phi -prune -o -type f -print | while read -r f; do
        mkdir -p "$1/$(dirname "$f")"
        cp "$f" "$1/$f"
    done)
}

same_phi() {
    if diff -rq "$REF/phi" "$1/phi" >/dev/null; then
        echo "   phi: the same bytes as the reference ($(find "$REF/phi" -type f | wc -l) files)"
    else
        echo "   phi DIFFERS from the reference"
        diff -rq "$REF/phi" "$1/phi" | head
        exit 1
    fi
}

echo "== budget: the same labels with --mem $BIG (every level in memory)"
fresh "$DIR/big.harmap"
/usr/bin/time -f "   %e s wall, peak RSS %M KiB" "$H" -q solve "$DIR/big.harmap" --mem "$BIG" --checkpoint-every 0
same_phi "$DIR/big.harmap"
rm -rf "$DIR/big.harmap"

echo "== resume: killed three times with SIGKILL, --mem $MEM, checkpoints every $EVERY"
K=$DIR/killed.harmap
fresh "$K"
resume=()
for wait in $KILLS; do
    "$H" -q solve "$K" --mem "$MEM" --checkpoint-every "$EVERY" "${resume[@]}" &
    pid=$!
    # Wait for the first checkpoint of this process, then let it run $wait seconds more.
    start=$(date +%s)
    while [ ! -e "$K/solve/manifest.json" ] || [ "$(stat -c %Y "$K/solve/manifest.json")" -lt "$start" ]; do
        sleep 0.2
        kill -0 $pid 2>/dev/null || { echo "   the solve finished before the kill: use a larger N"; exit 1; }
    done
    sleep "$wait"
    kill -0 $pid 2>/dev/null || { echo "   the solve finished before the kill: use a larger N"; exit 1; }
    kill -9 $pid
    wait $pid 2>/dev/null || true
    it=$(grep -o '"iterations": [0-9]*' "$K/solve/manifest.json" | head -1)
    echo "   killed after ${wait}s more; newest checkpoint: $it"
    resume=(--resume)
done
/usr/bin/time -f "   resumed to the end: %e s wall, peak RSS %M KiB" "$H" -q solve "$K" --mem "$MEM" --resume
same_phi "$K"
[ -d "$K/solve" ] && { echo "   solver state left behind"; exit 1; }
echo "== all checks passed"
