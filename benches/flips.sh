#!/usr/bin/env bash
# The sphere map's bijectivity with surface seeds, one row per shape:
#
#   benches/flips.sh BINARY OUTDIR [RESOLUTION]
#
# Every mesh in ../shared/data/meshes that voxelizes at RESOLUTION (default 128) to one
# genus-0 piece, and those the voxelizer's topology repair made one (marked "repaired":
# not the issue's set; the ones refused are listed as skipped on stderr), and
# the built-in starfish as `harmap run` makes it. Each is voxelized, solved and traced
# with `--seeds surface`; the table gives the flipped triangles (of those measured), the
# colliding seeds (within 0.05 degrees of a seed more than 5 voxels away), the
# indistinguishable seeds (stored arrival directions equal to those of a seed from
# another place; "n/a" for a binary that does not count them) and the share of seeds
# that reached the center. With `--map` after RESOLUTION it also maps the volume and
# prints the folded voxels (for binaries that count them).
# Needs jq and ../shared/data (HARMAP_DATA).
set -euo pipefail
bin=$(realpath "$1")
out=$2
res=${3:-128}
map=${4:-}
here=$(cd "$(dirname "$0")/.." && pwd)
data=${HARMAP_DATA:-$here/../shared/data}
mkdir -p "$out"
out=$(realpath "$out")

row() { # NAME RUN
    local j
    j=$("$bin" info "$2" --json)
    local fl ms co ind re fo vx
    vx=$(jq -r '.summary.voxelize.repair | if . == null then "as is" else "repaired" end' <<<"$j")
    fl=$(jq -r '.summary.trace.surface.flipped // "n/a"' <<<"$j")
    ms=$(jq -r '.summary.trace.surface.measured // "n/a"' <<<"$j")
    co=$(jq -r '.summary.trace.collisions.seeds // "n/a"' <<<"$j")
    ind=$(jq -r '.harmap.stages.trace.result.indistinguishable.seeds // "n/a"' <<<"$j")
    re=$(jq -r '(.summary.trace.reached_fraction // 0) * 100 | . * 1000 | round / 1000' <<<"$j")
    fo=$(jq -r '.harmap.stages.map.result.folded.voxels // "n/a"' <<<"$j")
    if [[ -n $map ]]; then
        printf '%-18s %-9s %12s %10s %18s %9s %8s\n' "$1" "$vx" "$fl/$ms" "$co" "$ind" "$re" "$fo"
    else
        printf '%-18s %-9s %12s %10s %18s %9s\n' "$1" "$vx" "$fl/$ms" "$co" "$ind" "$re"
    fi
}

if [[ -n $map ]]; then
    printf '%-18s %-9s %12s %10s %18s %9s %8s\n' mesh voxelized flipped colliding indistinguishable reached% folded
else
    printf '%-18s %-9s %12s %10s %18s %9s\n' mesh voxelized flipped colliding indistinguishable reached%
fi
for m in "$data"/meshes/*; do
    name=$(basename "$m")
    name=${name%%.*}
    r="$out/$name.harmap"
    rm -rf "$r"
    if ! "$bin" -q --progress never voxelize "$m" -o "$r" --resolution "$res" \
        >"$out/$name.voxelize.log" 2>&1; then
        echo "$name: skipped (refused: $(grep -m1 -v "^\s*$" "$out/$name.voxelize.log" | cut -c1-80))" >&2
        continue
    fi
    "$bin" -q --progress never solve "$r" >/dev/null
    "$bin" -q --progress never trace "$r" --seeds surface >/dev/null
    if [[ -n $map ]]; then
        "$bin" -q --progress never map "$r" >/dev/null
    fi
    row "$name" "$r"
done
r="$out/starfish.harmap"
rm -rf "$r"
(cd "$out" && "$bin" -q --progress never run -o "$r" >/dev/null)
row starfish "$r"
