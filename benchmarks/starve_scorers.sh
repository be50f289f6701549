#!/bin/bash
# Starve both scorer shards of CPU mid-run (docs/bus.md, "Starved scorers"): the soak topology (bench_soak.py) with
# both scorer processes put in a cgroup-v1 cpu group for STARVE_S seconds, rejected payloads kept (HYDROWATCH_QUARANTINE).
# As root, where /sys/fs/cgroup/cpu exists. MAIN_ONLY=1 starves only their Python thread (zenoh's threads run).
# usage: benchmarks/starve_scorers.sh OUTDIR [MINUTES 10] [START_S 200] [STARVE_S 120] [QUOTA_US 3000 of 100000]
set -e
out=$1; minutes=${2:-10}; start=${3:-200}; starve=${4:-120}; quota=${5:-3000}
cd "$(dirname "$0")/.."
mkdir -p "$out"
export HYDROWATCH_QUARANTINE=$out/quarantine
.venv/bin/python benchmarks/bench_soak.py --machines 1000 --speed 0.25 --minutes "$minutes" --warmup-minutes 5 \
    --keep "$out/keep" > "$out/soak.txt" 2>&1 &
bench=$!
sleep "$start"
cg=/sys/fs/cgroup/cpu/hydrowatch-starve
mkdir -p $cg; echo 100000 > $cg/cpu.cfs_period_us; echo "$quota" > $cg/cpu.cfs_quota_us
pids=$(pgrep -f "services.scorer")
echo "$(date +%T) starving scorers: $pids" >> "$out/starve.log"
for pid in $pids; do
  if [ -n "$MAIN_ONLY" ]; then echo "$pid" > $cg/tasks
  else for t in /proc/"$pid"/task/*; do echo "${t##*/}" > $cg/tasks 2>/dev/null || true; done; fi
done
sleep "$starve"
for pid in $pids; do for t in /proc/"$pid"/task/*; do echo "${t##*/}" > /sys/fs/cgroup/cpu/tasks 2>/dev/null || true; done; done
echo "$(date +%T) released" >> "$out/starve.log"
wait $bench
echo "$(date +%T) done; rejected payloads in $out/quarantine, summary in $out/soak.txt" >> "$out/starve.log"
