#!/usr/bin/env bash
# The figures of the README's Slurm section: one process against the job array of N chunks plus
# the merge, on a throw-away one-node cluster on this machine (tests/slurm/cluster.sh; as root,
# with `./setup.sh --tests` done), then the merge alone, the sizes, and a bitwise comparison.
#
#   scripts/slurm/bench-one-node.sh [N] [render flags...]
#   (default: 3 chunks of vase --method mis-exact --window 7 --spp 1 --exr-float)
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
B=$root/target/release/reframe
[ -x "$B" ] || { echo "build first: cargo build --release" >&2; exit 1; }
n=${1:-3}; shift || true
R=("$@"); [ ${#R[@]} -gt 0 ] || R=(vase --method mis-exact --window 7 --spp 1 --exr-float)
D=$(mktemp -d); trap '"$root/tests/slurm/cluster.sh" stop "$D/cluster"; rm -rf "$D"' EXIT
now() { date +%s.%N; }
since() { awk -v a="$1" -v b="$(now)" 'BEGIN { printf "%.1f", b - a }'; }
one() { local s; s=$(now); "$B" render "${R[@]}" --out "$D/$1/f_####.exr" >/dev/null 2>&1; echo "one process: $(since "$s") s"; }
one one1
export SLURM_CONF; SLURM_CONF=$("$root/tests/slurm/cluster.sh" start "$D/cluster")
for cpt in "$(nproc)" 1; do
  s=$(now)
  "$root/scripts/slurm/submit.sh" -n "$n" --reframe "$B" --logs "$D/logs$cpt" \
    --sbatch=--cpus-per-task="$cpt" -- "${R[@]}" --out "$D/arr$cpt/f_####.exr" >/dev/null
  read -r _ m < "$D/logs$cpt/last-submission"
  while scontrol show job -o "$m" | grep -qE "JobState=(PENDING|RUNNING|COMPLETING)"; do sleep 0.2; done
  echo "array of $n + merge, --cpus-per-task=$cpt: $(since "$s") s, $(scontrol show job -o "$m" | grep -o 'JobState=[A-Z]*')"
  grep -h merged "$D/logs$cpt"/merge-*.log
  grep -h rendered "$D/logs$cpt"/chunk-*.log | sed 's/.*rendered /  /'
done
one one2
s=$(now); "$B" merge --chunks "$n" --out "$D/arr1/f_####.exr" >/dev/null 2>&1
echo "merge alone: $(since "$s") s"
echo "partial files: $(cat "$D"/arr1/*.partial | wc -c) bytes; frames: $(cat "$D"/arr1/*.exr | wc -c) bytes"
same=0; all=0
for f in "$D"/one1/*.exr; do
  all=$((all + 1))
  oiiotool --fail 0 --failpercent 0 --warn 0 --diff "$f" "$D/arr1/$(basename "$f")" | grep -q '^PASS' && same=$((same + 1))
done
echo "bitwise identical frames: $same of $all"
