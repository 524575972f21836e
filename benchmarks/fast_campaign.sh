#!/bin/sh
# Issue 22's benchmark in chunks of 50 seeds, one niced process at a time, resumable: a chunk
# whose .npz exists is not run again, so kill it and start it again at will. The paper's unit
# at the three flicker cut-offs first (every cut-off gets a chunk before any gets its next), then
# the VN-100 and MTi configs; each against the plan `fieldcal plan --target field-18` writes for
# its config. Then, per config and cut-off:
#   python benchmarks/fast.py report --reference DIR/sim-5e3-field-18-*.npz --planned DIR/sim-5e3-planned-sim-*.npz
#   python benchmarks/fast.py report --reference DIR/vn100-own-field-18-*.npz --planned DIR/vn100-own-planned-vn100-*.npz
# Usage: benchmarks/fast_campaign.sh DIR [RUNS]   (RUNS per procedure and case, default 200)
set -eu
dir=${1:?usage: fast_campaign.sh DIR [RUNS]}
runs=${2:-200}
here=$(cd "$(dirname "$0")/.." && pwd)
py="$here/.venv/bin/python"
fast="$here/benchmarks/fast.py"
mkdir -p "$dir"
for config in sim vn100 mti; do
  [ -f "$dir/planned-$config.yaml" ] || nice -n 10 "$here/.venv/bin/fieldcal" plan --config "$config" \
    --target field-18 --out "$dir/planned-$config.yaml" > "$dir/planned-$config.txt"
done
chunk() {  # config, cut-off (or "" for the config's own), first seed
  for procedure in field-18 "$dir/planned-$1.yaml"; do
    name=$(basename "$procedure" .yaml)
    out="$dir/$1-${2:-own}-$name-$3.npz"
    [ -f "$out" ] && continue
    nice -n 10 "$py" "$fast" mc --config "$1" ${2:+--flicker-tau-max "$2"} --procedure "$procedure" \
      --runs 50 --first-seed "$3" --out "$out.part.npz" 2>/dev/null && mv "$out.part.npz" "$out"
    echo "$(date -u +%H:%M:%S) $out"
  done
}
first=0
while [ "$first" -lt "$runs" ]; do
  for tau in 5e3 1e5 1e6; do chunk sim "$tau" "$first"; done
  first=$((first + 50))
done
first=0
while [ "$first" -lt "$runs" ]; do
  for config in vn100 mti; do chunk "$config" "" "$first"; done
  first=$((first + 50))
done
