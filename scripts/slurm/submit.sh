#!/usr/bin/env bash
# Render an animation on a Slurm cluster: a job array of N chunks (`reframe render --chunk K/N`)
# and a merge job (`reframe merge`) that starts when every chunk has succeeded
# (--dependency=afterok). The reframe binary, the scene and the --out folder must be reachable
# from every node (a shared file system).
#
#   scripts/slurm/submit.sh -n 8 [--reframe PATH] [--logs DIR] [--only K,K..] [--sbatch ARG].. \
#       -- SCENE --out /shared/out/shot_####.exr [render flags: --method mis-exact --window 7 ...]
#
#   -n N            number of chunks (array tasks)
#   --reframe PATH  the reframe binary (default: `reframe` on PATH, else this checkout's
#                   target/release/reframe), made absolute
#   --logs DIR      folder of the jobs' logs (default: slurm-logs), chunk-<array>_<K>.log and
#                   merge-<job>.log
#   --only K,K..    resubmit only these chunks (after one failed), with a new merge job
#   --sbatch ARG    passed to both sbatch calls (e.g. --sbatch=--partition=render), repeatable
#
# With --stats FILE among the render flags, each chunk writes its own report, FILE with
# .chunk-K-of-N before its extension (stats.json: stats.chunk-3-of-8.json).
#
# With --denoise among the render flags, the merge job denoises the merged frames: it is given
# SCENE (the first render argument) to trace the denoiser's guides in.
#
# Prints the two job ids; follow with `squeue -u $USER` and `tail -f DIR/chunk-*.log`.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
die() { echo "submit.sh: $*" >&2; exit 2; }
n=""; only=""; logs=slurm-logs; extra=()
reframe=$(command -v reframe || echo "$here/../../target/release/reframe")
while [ $# -gt 0 ]; do
  case "$1" in
    -n) n=${2:?}; shift 2 ;;
    --reframe) reframe=${2:?}; shift 2 ;;
    --logs) logs=${2:?}; shift 2 ;;
    --only) only=${2:?}; shift 2 ;;
    --sbatch=*) extra+=("${1#--sbatch=}"); shift ;;
    --sbatch) extra+=("${2:?}"); shift 2 ;;
    --) shift; break ;;
    *) die "unknown option $1 (render flags go after --)" ;;
  esac
done
[[ "$n" =~ ^[1-9][0-9]*$ ]] || die "-n N: the number of chunks is required"
[ -x "$reframe" ] || die "reframe binary $reframe not found or not executable (--reframe PATH)"
reframe=$(realpath "$reframe")
[ $# -gt 0 ] || die "no render arguments after --"
out=""; denoise=""
args=("$@")
for ((i = 0; i < ${#args[@]}; i++)); do
  case "${args[i]}" in
    --out) out=${args[i+1]:-} ;;
    --out=*) out=${args[i]#--out=} ;;
    --denoise) denoise=1 ;;
    --chunk|--chunk=*) die "--chunk is set per array task; leave it out" ;;
    # One folder for every chunk: chunks running side by side refused each other's lock.
    --checkpoint|--checkpoint=*) die "--checkpoint: each chunk keeps its own checkpoint beside its partial file; leave it out" ;;
  esac
done
[ -n "$out" ] || die "--out PATTERN is required: a folder every node can reach"
merge_args=("$out")
if [ -n "$denoise" ]; then
  [[ "${args[0]}" != -* ]] || die "--denoise: the scene must be the first render argument (the merge denoises in it)"
  merge_args+=("${args[0]}")
fi
array="1-$n"
if [ -n "$only" ]; then
  [[ "$only" =~ ^[0-9]+(,[0-9]+)*$ ]] || die "--only $only: expected K or K,K,.."
  for k in ${only//,/ }; do [ "$k" -ge 1 ] && [ "$k" -le "$n" ] || die "--only: chunk $k not in 1..$n"; done
  array=$only
fi
mkdir -p "$logs"
# The binary's path and the chunk count reach the jobs through this environment, which
# --export=ALL hands them whole: in the --export list itself a path with a comma was cut there.
export REFRAME=$reframe REFRAME_CHUNKS=$n
env=(--export=ALL)
chunks=$(sbatch --parsable "${extra[@]}" "${env[@]}" --array="$array" \
  --output="$logs/chunk-%A_%a.log" "$here/chunk.sbatch" "$@")
chunks=${chunks%%;*}
merge=$(sbatch --parsable "${extra[@]}" "${env[@]}" --dependency="afterok:$chunks" \
  --kill-on-invalid-dep=yes --output="$logs/merge-%j.log" "$here/merge.sbatch" "${merge_args[@]}")
merge=${merge%%;*}
echo "chunks: array job $chunks (tasks $array of $n); merge: job $merge (after all succeed)"
echo "$chunks $merge" > "$logs/last-submission"
