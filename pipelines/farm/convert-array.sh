#!/usr/bin/env bash
# Slurm job array: convert the Nth line of a file list into OUT_DIR.
#   sbatch --array=1-$(wc -l < inputs.txt) pipelines/farm/convert-array.sh inputs.txt OUT_DIR EXT [knitvox convert flags...]
# Exit codes (docs/guides/cli.md): 0 ok, 65/66 bad or missing input (no retry), 74 output failure, 75 transient (requeued).
#SBATCH --job-name=knitvox-convert
#SBATCH --cpus-per-task=2
#SBATCH --requeue
set -uo pipefail
list=$1 out_dir=$2 ext=$3
shift 3
task=${SLURM_ARRAY_TASK_ID:?run as a Slurm array job}
input=$(sed -n "${task}p" "$list")
[ -n "$input" ] || { echo "no line $task in $list" >&2; exit 65; }
name=$(basename "${input%.*}")
mkdir -p "$out_dir"
knitvox convert "$input" "$out_dir/$name.$ext" "$@"
rc=$?
if [ "$rc" -eq 75 ] && [ -n "${SLURM_JOB_ID:-}" ]; then
  echo "transient failure on $input: requeueing" >&2
  scontrol requeue "$SLURM_JOB_ID"
fi
exit "$rc"
