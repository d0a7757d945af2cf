#!/bin/bash
# Run a btfquilt batch plan as a Slurm job array: array task INDEX of COUNT
# runs `btfquilt batch PLAN -o OUT --shard INDEX/COUNT`, a deterministic
# contiguous 1/COUNT of the plan's jobs. The shards together run every job
# exactly once, into one shared output folder, with byte-identical results
# whatever COUNT is.
#
#   sbatch --export=ALL,PLAN=/shared/plan.toml,OUT=/shared/out examples/cluster/slurm_batch.sh
#
# PLAN and OUT must lie on a filesystem every node sees. BTFQUILT names the
# binary (default: `btfquilt` on PATH). Change --array to change the shard
# count: COUNT is read from Slurm, so nothing else needs editing.
#
# Optional (recommended on several nodes) first step: make the shared
# artifacts (geometry images, factorizations) once, with a small array, and
# start the jobs after it. Without it every shard makes the shared artifacts
# its jobs need, so shards on different nodes may make the same one at the
# same time: wasted time, not wrong results (both write the same bytes, and
# a process never removes a partial file written on another host):
#
#   shared=$(sbatch --parsable --array=0-3 --export=ALL,PLAN=…,OUT=…,STAGES=shared \
#            examples/cluster/slurm_batch.sh)
#   sbatch --dependency=afterok:"$shared" --export=ALL,PLAN=…,OUT=… \
#          examples/cluster/slurm_batch.sh
#
# (afterok waits for every shared task to succeed; with afterany the jobs
# start anyway and make a missing shared artifact themselves. Both arrays
# append to $OUT/manifests/slurm-INDEX.jsonl, one after the other.)
#
# A preempted, killed or failed task can simply be run again (`scontrol
# requeue JOBID_INDEX`, or resubmit the array): finished jobs are skipped
# and the hidden partial folders of killed ones are removed.
#
# Outside Slurm (for a test), set the SLURM_* variables by hand:
#   SLURM_ARRAY_TASK_ID=0 SLURM_ARRAY_TASK_COUNT=4 SLURM_ARRAY_TASK_MIN=0 \
#   SLURM_CPUS_PER_TASK=1 PLAN=plan.toml OUT=out bash examples/cluster/slurm_batch.sh
#
#SBATCH --job-name=btfquilt-batch
#SBATCH --array=0-15
#SBATCH --cpus-per-task=4
#SBATCH --mem=3G
#SBATCH --time=04:00:00
#SBATCH --requeue
#SBATCH --output=btfquilt-batch-%A_%a.log
# No --ntasks: one process per array task, using --cpus-per-task threads.

set -euo pipefail

: "${PLAN:?set PLAN to the plan file (sbatch --export=ALL,PLAN=...,OUT=...)}"
: "${OUT:?set OUT to the output folder}"
BTFQUILT="${BTFQUILT:-btfquilt}"
STAGES="${STAGES:-all}"        # "shared" for the optional first step
MEMORY="${MEMORY:-2560MiB}"    # btfquilt's budget, a bit under --mem (the process needs some more)

# Shard index from the array task: --array=0-15, 1-16 or 0-30:2 all give
# 0..15 of 16 (a list such as --array=1,5,9 does not: use a range; a
# throttle such as --array=0-15%4 is fine).
: "${SLURM_ARRAY_TASK_ID:?not a Slurm array task (set SLURM_ARRAY_TASK_ID by hand to test)}"
COUNT="${SLURM_ARRAY_TASK_COUNT:?}"
INDEX=$(( (SLURM_ARRAY_TASK_ID - ${SLURM_ARRAY_TASK_MIN:-0}) / ${SLURM_ARRAY_TASK_STEP:-1} ))
if (( INDEX < 0 || INDEX >= COUNT )); then
    echo "error: array task $SLURM_ARRAY_TASK_ID gives shard $INDEX, not in 0..$((COUNT - 1))" >&2
    exit 2
fi
THREADS="${SLURM_CPUS_PER_TASK:-1}"

echo "btfquilt batch: shard $INDEX/$COUNT ($STAGES) on $(hostname), $THREADS threads" >&2
mkdir -p "$OUT/manifests"
# One manifest per task: concurrent tasks never append to the same file.
# (Afterwards: cat "$OUT"/manifests/slurm-*.jsonl to see them all.)
exec "$BTFQUILT" batch "$PLAN" -o "$OUT" \
    --shard "$INDEX/$COUNT" \
    --stages "$STAGES" \
    --threads "$THREADS" \
    --memory "$MEMORY" \
    --manifest "$OUT/manifests/slurm-$INDEX.jsonl" \
    -q
