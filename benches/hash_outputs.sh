#!/usr/bin/env bash
# Hash what harmap computes, so that a change meant to keep behaviour can be checked bit
# for bit against the binary before it:
#
#   benches/hash_outputs.sh OLD_BINARY /tmp/old > old.txt
#   benches/hash_outputs.sh target/release/harmap /tmp/new > new.txt
#   diff old.txt new.txt
#
# Cases: the standard ball at 128 (labels to theta and psi), spot and cheburashka at
# resolution 128 with surface and with boundary seeds, crambin (1crn) at 0.5 A and the
# built-in starfish. For each run it prints the SHA-256 of the decoded contents of
# labels, phi, theta, psi and every seed table column (the decoded values, not the chunk
# files, so a change of codec alone does not count as a change of result).
# Needs python3 with zarr >= 3 and numpy (HARMAP_PYTHON, default .venv/bin/python) and
# ../shared/data.
set -euo pipefail
bin=$(realpath "$1")
out=$2
here=$(cd "$(dirname "$0")/.." && pwd)
data=${HARMAP_DATA:-$here/../shared/data}
py=${HARMAP_PYTHON:-$here/.venv/bin/python}
rm -rf "$out"
mkdir -p "$out"
cd "$out"

"$bin" -q bench map --n 128 --dir "$out/ball" --keep >/dev/null
"$bin" -q --progress never trace "$out/ball/bench-solve-128.harmap" --seeds boundary >/dev/null
run_one() { # NAME ARGS...
    local name=$1
    shift
    "$bin" -q --progress never run "$@" -o "$out/$name.harmap" >/dev/null
}
run_one starfish
run_one spot-surface "$data/meshes/spot.obj" --resolution 128
run_one spot-boundary "$data/meshes/spot.obj" --resolution 128 --seeds boundary
run_one cheburashka-surface "$data/meshes/cheburashka.obj" --resolution 128
run_one cheburashka-boundary "$data/meshes/cheburashka.obj" --resolution 128 --seeds boundary
run_one 1crn "$data/molecules/1crn.pdb" --spacing 0.5

"$py" - "$out" <<'PY'
import hashlib, pathlib, sys
import numpy as np
import zarr

root = pathlib.Path(sys.argv[1])
runs = sorted(p for p in root.rglob("*") if p.is_dir() and (p / "labels").is_dir()
              and (p / "zarr.json").is_file())
for run in runs:
    name = str(run.relative_to(root))
    arrays = ["labels/0", "phi/0", "theta/0", "psi/0"]
    seeds = run / "seeds"
    if seeds.is_dir():
        arrays += sorted("seeds/" + p.name for p in seeds.iterdir() if p.is_dir())
    for a in arrays:
        if not (run / a).is_dir():
            print(f"{name} {a} absent")
            continue
        v = np.ascontiguousarray(zarr.open_array(str(run / a), mode="r")[...])
        print(f"{name} {a} {v.dtype} {v.shape} {hashlib.sha256(v.tobytes()).hexdigest()[:16]}")
PY
