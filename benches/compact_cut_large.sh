#!/usr/bin/env bash
# The topology repair's compact cut out of core on a grid of 10^9 voxels, shown with
# the real binary and the default command a user would run.
#
#   benches/compact_cut_large.sh [N] [MEM] [DIR]     (defaults: 1000 1GiB /tmp/harmap-cut-large)
#
# 1. benches/handles_volume.py writes an N^3 u8 label volume: a ball of radius 0.44 N
#    with 8 thin rings half sunk into its surface (genus 8, 39% of the grid solid);
# 2. `harmap voxelize VOL.raw --raw-shape N,N,N --raw-dtype u8 -o RUN --mem MEM` under
#    /usr/bin/time -v: the grid is over 32 Mi voxels, so the repair is the compact cut;
# 3. prints wall time, peak resident memory, the stage's timings and the repair's report
#    (handles cut, voxels removed, the cache's misses) from the run's metadata.
# Needs about 2.2 N^3 bytes of disk in DIR (volume, solid scratch, bricks) at once.
set -euo pipefail

N=${1:-1000}
MEM=${2:-1GiB}
DIR=${3:-/tmp/harmap-cut-large}
cd "$(dirname "$0")/.."
cargo build --release --quiet
H=$PWD/target/release/harmap
mkdir -p "$DIR"
VOL=$DIR/handles$N.raw
[ -f "$VOL" ] || python3 benches/handles_volume.py "$VOL" "$N" 8
RUN=$DIR/handles$N.harmap
rm -rf "$RUN"
/usr/bin/time -v "$H" voxelize "$VOL" --raw-shape "$N,$N,$N" --raw-dtype u8 -o "$RUN" \
    --mem "$MEM" 2> "$DIR/time.txt" | tail -2
grep -E "Elapsed|Maximum resident|User time|System time" "$DIR/time.txt"
python3 - "$RUN" <<'PY'
import json, sys
r = json.load(open(sys.argv[1] + "/zarr.json"))["attributes"]["harmap"]["stages"]["voxelize"]["result"]
print("timings:", {k: round(v, 1) for k, v in r["timings"]})
t = r["repair"]
keys = ("genus_before", "method", "handles_cut", "voxels_removed", "fraction", "seconds")
print("repair:", {k: t[k] for k in keys}, "scratch_brick_reads:", t.get("scratch_brick_reads"))
PY
