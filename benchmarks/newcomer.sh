#!/usr/bin/env bash
# A newcomer's first hour (issue 24): the README's two commands on a fresh clone with empty
# caches, timed step by step.  One repetition per call; BENCHMARKS.md's "newcomer" table holds
# the medians of three.  Run it on an idle machine (it records the load average it saw).
#
#   benchmarks/newcomer.sh REPO WORKDIR   ->  WORKDIR/newcomer.tsv (one line per step)
#
# Steps: `make setup` (venv and pip from the package index), the machine's yardstick
# (benchmarks/yardstick.py: a fixed NumPy workload that follows the run's speed only
# sometimes, BENCHMARKS.md), `make run` (default config, compiles included), `make run`
# again (nothing to do), `make test`, the yardstick again.  The caches (pip, compiled Stan
# programs, httpstan, Snakemake, matplotlib) all live under XDG_CACHE_HOME, which points at
# an empty folder inside WORKDIR.
set -euo pipefail
repo=${1:?usage: newcomer.sh REPO WORKDIR}
work=${2:?usage: newcomer.sh REPO WORKDIR}
mkdir -p "$work"
work=$(cd "$work" && pwd)
[[ -e $work/clone ]] && { echo "newcomer: $work/clone exists; give an empty WORKDIR" >&2; exit 2; }
git clone -q "$repo" "$work/clone"
export XDG_CACHE_HOME=$work/cache MPLCONFIGDIR=$work/cache/matplotlib
mkdir -p "$XDG_CACHE_HOME"
unset PYTHONPATH SSMOBS_CACHE
commit=$(git -C "$work/clone" rev-parse --short HEAD)
out=$work/newcomer.tsv
printf 'step\twall_s\tcpu_s\trc\tload1_before\tload1_after\tcommit\tstarted\n' >"$out"

step() {  # step NAME COMMAND...: time one command in the clone, log to WORKDIR/NAME.log
  local name=$1 rc load0 t0 t1 cpu started
  shift
  started=$(date -u +%FT%TZ)
  load0=$(cut -d' ' -f1 /proc/loadavg)
  t0=$(date +%s.%N)
  rc=0
  # the children's CPU time of a subshell that runs the step (bash's `times`)
  (cd "$work/clone" && "$@" >"$work/$name.log" 2>&1; ec=$?; times >"$work/$name.times"; exit $ec) || rc=$?
  t1=$(date +%s.%N)
  cpu=$(awk 'NR == 2 { split($1, u, /[ms]/); split($2, s, /[ms]/); print u[1] * 60 + u[2] + s[1] * 60 + s[2] }' "$work/$name.times")
  printf '%s\t%.1f\t%.1f\t%s\t%s\t%s\t%s\t%s\n' "$name" "$(awk "BEGIN { print $t1 - $t0 }")" "$cpu" "$rc" \
    "$load0" "$(cut -d' ' -f1 /proc/loadavg)" "$commit" "$started" >>"$out"
  last_t0=$t0 last_t1=$t1 last_cpu=$cpu last_rc=$rc
  return 0
}

step setup make setup
step yardstick_before .venv/bin/python benchmarks/yardstick.py
step run make run
# the default profile's outputs with the provenance of this run, ready to be committed
if [[ $last_rc == 0 ]]; then
  (cd "$work/clone" && .venv/bin/python -m ssmobs.provenance --config config/config.yaml \
    --command "make run" --started "$last_t0" --finished "$last_t1" \
    --cpu-seconds "$last_cpu" --from-empty-results yes \
    --note "benchmarks/newcomer.sh: a fresh clone with empty caches, compiles included")
fi
step rerun make run
step test make test
step yardstick_after .venv/bin/python benchmarks/yardstick.py
cat "$out"
cat "$work"/yardstick_*.log
