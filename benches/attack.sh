#!/usr/bin/env bash
# Replay the heavier reliability cases of issue 30 against a harmap binary and print a
# table of case / expected / got / verdict:
#
#   benches/attack.sh [BINARY] [WORKDIR]
#
# Cases: exports killed at random moments (then the same export again: it must succeed
# and leave no .partial file), `harmap run` killed at random moments (then run again:
# it must finish), endless and gzip-bomb inputs under --mem (exit 2, peak resident
# memory within --mem plus the fixed allowance of docs/guide.md), far atoms and huge
# grids (exit 2 at once, readable numbers), a flipped byte and a deleted chunk (exit 2,
# the array and chunk named), --threads 10000 (capped, finishes), SIGINT and SIGTERM at
# random moments of `harmap run` (exit 130 or 143 within a second, the same command
# finishes), and a full disk on a small tmpfs where the machine lets us mount one (root):
# a whole run, then solve, trace, map and an export each on a filled disk (the stage
# fails, nothing is left, the run still opens, and a run on the freed disk finishes).
# Needs ../shared/data (the spot mesh, 1crn). KILLS (default 8) sets the repetitions.
set -uo pipefail
here=$(cd "$(dirname "$0")/.." && pwd)
bin=$(realpath "${1:-$here/target/release/harmap}")
work=${2:-$(mktemp -d)}
data=${HARMAP_DATA:-$here/../shared/data}
kills=${KILLS:-8}
mkdir -p "$work"
cd "$work" || exit 1
h() { "$bin" -q --progress never "$@"; }

rows=()
row() { # CASE EXPECTED GOT OK
    rows+=("$(printf '%-38s | %-34s | %-40s | %s' "$1" "$2" "$3" "$4")")
}
verdict() { if [ "$1" = "$2" ]; then echo ok; else echo FAIL; fi; }
# Peak resident memory (MiB) and exit code of a command, through /usr/bin/time.
peak() {
    /usr/bin/time -f '%M' -o "$work/time.txt" "$@" >/dev/null 2>"$work/err.txt"
    local code=$?
    echo "$(($(tail -1 "$work/time.txt") / 1024)) $code"
}
# Pseudo-random sleep of 0.05 .. 1.5 s, reproducible.
RANDOM=30
nap() { sleep "$(printf '0.%02d' $((RANDOM % 95 + 5)))"; [ $((RANDOM % 3)) = 0 ] && sleep 0.5; }

mesh=$data/meshes/spot.obj
R=$work/spot.harmap
rm -rf "$R"
h run "$mesh" -o "$R" --resolution 96 || { echo "cannot make the run"; exit 1; }

# 1. Exports killed at random moments, then the same export again.
left=0 bad=0
for i in $(seq "$kills"); do
    for fmt in vti nifti ome-zarr; do
        out=$work/exp.$fmt
        "$bin" -q --progress never export "$R" --format "$fmt" -o "$out" >/dev/null 2>&1 &
        pid=$!
        nap
        kill -9 "$pid" 2>/dev/null
        wait "$pid" 2>/dev/null
        h export "$R" --format "$fmt" -o "$out" >/dev/null 2>&1 || bad=$((bad + 1))
    done
done
left=$(find "$work" -maxdepth 1 -name '.*partial*' | wc -l)
row "export killed x$((kills * 3)), then again" "all succeed, 0 partial files" "$bad failed, $left partial files" \
    "$(verdict "$bad/$left" "0/0")"

# 2. harmap run killed at random moments, then run again.
bad=0
for i in $(seq "$kills"); do
    K=$work/killed.harmap
    rm -rf "$K" "$K".*
    "$bin" -q --progress never run "$mesh" -o "$K" --resolution 64 >/dev/null 2>&1 &
    pid=$!
    nap
    nap
    kill -9 "$pid" 2>/dev/null
    wait "$pid" 2>/dev/null
    h run "$mesh" -o "$K" --resolution 64 >/dev/null 2>&1 || bad=$((bad + 1))
done
row "run killed x$kills, then run again" "all finish" "$bad failed" "$(verdict "$bad" 0)"

# 3. Endless streams and a gzip bomb under --mem 256MiB.
python3 - "$work/bomb.obj.gz" <<'PY'
import gzip, sys
with gzip.open(sys.argv[1], "wb", compresslevel=9) as f:
    for _ in range(1024):
        f.write(bytes(1 << 20))
PY
for ext in obj stl pdb obj.gz; do
    in=$work/zero.$ext
    if [ "$ext" = obj.gz ]; then in=$work/bomb.obj.gz; else ln -sf /dev/zero "$in"; fi
    read -r mib code < <(peak timeout 120 "$bin" -q voxelize "$in" -o "$work/z.harmap" --mem 256MiB)
    ok=$([ "$code" = 2 ] && [ "$mib" -le 320 ] && echo ok || echo FAIL)
    row "voxelize $(basename "$in") --mem 256MiB" "exit 2, peak <= 256+64 MiB" "exit $code, peak $mib MiB" "$ok"
done

# 4. Far atoms and huge grids.
atom() { printf 'ATOM      1  CA  ALA A   1    %8s   0.000   0.000  1.00  0.00           C\n' "$1"; }
{ atom 0.000; atom 1.0e15; } >"$work/apart.pdb"
atom 1.0e9 >"$work/far.pdb"
for f in apart far; do
    read -r mib code < <(peak "$bin" -q voxelize "$work/$f.pdb" -o "$work/z.harmap")
    row "voxelize $f.pdb" "exit 2, small peak" "exit $code, peak $mib MiB" \
        "$([ "$code" = 2 ] && [ "$mib" -le 100 ] && echo ok || echo FAIL)"
done
for opt in "--resolution 100000" "--spacing 1e-300"; do
    # shellcheck disable=SC2086
    "$bin" -q voxelize "$mesh" -o "$work/z.harmap" $opt >/dev/null 2>"$work/err.txt"
    code=$?
    len=$(wc -c <"$work/err.txt")
    row "voxelize spot $opt" "exit 2, short message" "exit $code, $len bytes" \
        "$([ "$code" = 2 ] && [ "$len" -lt 600 ] && echo ok || echo FAIL)"
done

# 5. Damaged and missing chunks.
D=$work/damaged.harmap
rm -rf "$D"
cp -r "$R" "$D"
python3 - "$D/phi/0/c/0/0/0" <<'PY'
import sys
p = sys.argv[1]
b = bytearray(open(p, "rb").read())
b[len(b) // 2] ^= 0x40
open(p, "wb").write(b)
PY
"$bin" -q export "$D" --format nifti -o "$work/d.nii" >/dev/null 2>"$work/err.txt"
code=$?
named=$(grep -c '/phi/0, chunk \[0, 0, 0\]' "$work/err.txt")
row "flipped byte in phi/0 chunk, export" "exit 2, names /phi/0 and chunk" "exit $code, named: $named" \
    "$([ "$code" = 2 ] && [ "$named" -ge 1 ] && echo ok || echo FAIL)"
rm -f "$D/labels/0/c/0/0/0"
"$bin" -q export "$D" --format nifti --field labels -o "$work/d.nii" >/dev/null 2>"$work/err.txt"
code=$?
named=$(grep -c '/labels/0.*missing' "$work/err.txt")
row "deleted labels/0 chunk, export" "exit 2, names it missing" "exit $code, named: $named" \
    "$([ "$code" = 2 ] && [ "$named" -ge 1 ] && echo ok || echo FAIL)"

# 6. --threads 10000.
ms() { echo $(($(date +%s%N) / 1000000)); }
start=$(ms)
"$bin" -q --threads 10000 voxelize "$mesh" -o "$work/t.harmap" --resolution 64 --force >/dev/null 2>"$work/err.txt"
code=$?
took=$(($(ms) - start))
row "--threads 10000 voxelize 64" "exit 0 with a warning, < 10 s" "exit $code in $took ms" \
    "$([ "$code" = 0 ] && grep -q warning "$work/err.txt" && [ "$took" -lt 10000 ] && echo ok || echo FAIL)"

# 6b. SIGINT and SIGTERM at random moments of `harmap run` (1crn, every stage over a
# second): exit 130 or 143 within a second, then the same command finishes the run.
pdb=$data/molecules/1crn.pdb
S=$work/signalled.harmap
rm -rf "$S" "$S".*
slow=0 wrong=0 unfinished=0
for i in $(seq "$kills"); do
    for sig in INT TERM; do
        rm -rf "$S" "$S".*
        "$bin" -q --progress never run "$pdb" -o "$S" --resolution 88 --method sor >/dev/null 2>&1 &
        pid=$!
        sleep "$(printf '%d.%02d' $((RANDOM % 11)) $((RANDOM % 100)))"
        kill -"$sig" "$pid" 2>/dev/null
        start=$(ms)
        wait "$pid"
        code=$?
        took=$(($(ms) - start))
        want=$([ "$sig" = INT ] && echo 130 || echo 143)
        [ "$code" = 0 ] && continue # finished before the signal
        [ "$code" = "$want" ] || wrong=$((wrong + 1))
        [ "$took" -le 1000 ] || slow=$((slow + 1))
        h run "$pdb" -o "$S" --resolution 88 --method sor >/dev/null 2>&1 || unfinished=$((unfinished + 1))
    done
done
row "run signalled x$((kills * 2)), continued" "130/143 in <= 1 s, then finishes" "$wrong wrong code, $slow slow, $unfinished unfinished" \
    "$(verdict "$wrong/$slow/$unfinished" 0/0/0)"

# 7. A full disk: a 6 MiB tmpfs, where mounting is allowed.
mnt=$work/full
mkdir -p "$mnt"
if mount -t tmpfs -o size=6m tmpfs "$mnt" 2>/dev/null; then
    "$bin" -q run "$mesh" -o "$mnt/R" --resolution 96 >/dev/null 2>"$work/err.txt"
    code=$?
    used=$(du -sk "$mnt" | cut -f1)
    partial=$(find "$mnt" -name '*.partial*' | wc -l)
    row "run on a full 6 MiB tmpfs" "exit != 0, no partial left" "exit $code, $partial partial, ${used} KiB used" \
        "$([ "$code" != 0 ] && [ "$partial" = 0 ] && echo ok || echo FAIL)"
    umount "$mnt"
    # Each later stage on a full disk: voxelize, fill the disk, solve; free it, solve,
    # fill it again, then trace, map and export.
    mount -t tmpfs -o size=24m tmpfs "$mnt"
    h voxelize "$mesh" -o "$mnt/R" --resolution 96 >/dev/null 2>&1
    fill() { head -c $((24 * 1024 * 1024)) /dev/zero >"$mnt/filler" 2>/dev/null; }
    bad="" codes=""
    on_full() { # STAGE ARGS...: run it on the full disk, check what is left
        "$bin" -q "$@" >/dev/null 2>"$work/err.txt"
        local code=$?
        codes="$codes $1:$code"
        local left
        left=$(find "$mnt" -name '*.partial*' -o -name '*.tmp-*' -o -name 'map.scratch' | wc -l)
        [ "$code" != 0 ] || bad="$bad $1:exit0"
        [ "$left" = 0 ] || bad="$bad $1:$left-left"
        "$bin" -q info "$mnt/R" >/dev/null 2>&1 || bad="$bad $1:unreadable"
    }
    fill
    on_full solve "$mnt/R"
    rm -f "$mnt/filler"
    h solve "$mnt/R" >/dev/null 2>&1 || bad="$bad solve-on-free-disk"
    fill
    on_full trace "$mnt/R" --seeds surface
    on_full map "$mnt/R"
    on_full export "$mnt/R" --format nifti -o "$mnt/x.nii"
    rm -f "$mnt/filler"
    h run "$mesh" -o "$mnt/R" --resolution 96 >/dev/null 2>&1 || bad="$bad rerun-failed"
    row "solve/trace/map/export on a full disk" "exit != 0, nothing left, run opens" "${codes# };${bad:- nothing left}" \
        "$([ -z "$bad" ] && echo ok || echo FAIL)"
    umount "$mnt"
else
    row "run on a full 6 MiB tmpfs" "exit != 0, no partial left" "not run: cannot mount a tmpfs" "n/a"
fi

printf '%-38s | %-34s | %-40s | %s\n' case expected got verdict
printf '%s\n' "${rows[@]}"
