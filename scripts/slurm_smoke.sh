#!/usr/bin/env bash
# A single-node Slurm on this machine, from the distribution's packages (slurmctld, slurmd,
# munge), running the job array `clipgaussian batch slurm` writes for a tiny batch (2 pictures x
# 2 styles, the tests' tiny models, cpu): submits it, waits, and checks results.csv.
#
# Run as root on Debian/Ubuntu: bash scripts/slurm_smoke.sh [work folder]
# It installs slurm-wlm and munge when missing, starts munged, slurmctld and slurmd with a
# configuration of its own under the work folder (nothing in /etc/slurm is changed), and stops
# them at the end. Takes about a minute after the build.
set -euo pipefail

work=$(realpath -m "${1:-/tmp/clipgaussian-slurm-smoke}")
repo=$(cd "$(dirname "$0")/.." && pwd)
rm -rf "$work"
mkdir -p "$work"/{spool,state,log}

if ! command -v slurmctld >/dev/null || ! command -v munged >/dev/null; then
  apt-get update -q
  DEBIAN_FRONTEND=noninteractive apt-get install -y -q slurm-wlm munge
fi

cargo build -q --manifest-path "$repo/Cargo.toml" -p clipgaussian --bin clipgaussian --example tiny_batch
bin="$repo/target/debug/clipgaussian"
manifest=$("$repo/target/debug/examples/tiny_batch" "$work/inputs")

# munge: a key if there is none, and the daemon.
if [ ! -s /etc/munge/munge.key ]; then
  mkdir -p /etc/munge
  dd if=/dev/urandom bs=1 count=1024 of=/etc/munge/munge.key 2>/dev/null
  chown munge:munge /etc/munge/munge.key 2>/dev/null || true
  chmod 400 /etc/munge/munge.key
fi
mkdir -p /run/munge && chown munge:munge /run/munge 2>/dev/null || true
pgrep -x munged >/dev/null || runuser -u munge -- munged || munged --force

host=$(hostname -s)
cpus=$(nproc)
memory=$(( $(awk '/MemTotal/ {print $2}' /proc/meminfo) / 1024 - 512 ))
export SLURM_CONF="$work/slurm.conf"
cat > "$SLURM_CONF" <<CONF
ClusterName=smoke
SlurmctldHost=$host
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
StateSaveLocation=$work/state
SlurmdSpoolDir=$work/spool
SlurmctldPidFile=$work/slurmctld.pid
SlurmdPidFile=$work/slurmd.pid
SlurmctldLogFile=$work/log/slurmctld.log
SlurmdLogFile=$work/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
ReturnToService=2
MpiDefault=none
JobAcctGatherType=jobacct_gather/none
NodeName=$host CPUs=$cpus RealMemory=$memory State=UNKNOWN
PartitionName=smoke Nodes=$host Default=YES MaxTime=INFINITE State=UP
CONF

slurmctld -f "$SLURM_CONF"
slurmd -f "$SLURM_CONF"
stop() {
  scancel --user=root 2>/dev/null || true
  pkill -x slurmd 2>/dev/null || true
  pkill -x slurmctld 2>/dev/null || true
}
trap stop EXIT
for _ in $(seq 60); do
  sinfo -h -o %T 2>/dev/null | grep -Eq 'idle|mixed' && break
  sleep 1
done
sinfo

batch="$work/batch"
"$bin" batch plan "$manifest" --out "$batch"
"$bin" batch slurm "$batch" --partition smoke --gpus 0 --cpus 1 --memory-gb 1 --time 00:10:00 --parallel 2
bash -n "$batch/batch.sbatch"
started=$(date +%s)
sbatch --wait "$batch/batch.sbatch"
echo "the array finished in $(( $(date +%s) - started )) s"
sacct -n -o JobID,State,ExitCode 2>/dev/null || squeue || true

"$bin" batch status "$batch"
"$bin" batch collect "$batch"
done_rows=$(tail -n +2 "$batch/results.csv" | grep -c ',done,' || true)
echo "results.csv: $done_rows of 4 jobs done"
ls "$batch/logs"
[ "$done_rows" -eq 4 ]
# Each job scored itself (the tiny batch asks for the CLIP metrics): a metrics.json each.
scored=$(ls "$batch"/*/metrics.json | wc -l)
echo "metrics: $scored of 4 jobs scored"
[ "$scored" -eq 4 ]
head -1 "$batch/results.csv" | grep -q ',clip_s,'

# Stops: a longer batch whose running tasks are signalled once a checkpoint is written, as
# Slurm signals them: USR1 to the script alone (`--signal=B:USR1@120`, the warning before a
# time limit) or TERM to every process of the task (a cancel or a preemption). Each stops with
# a checkpoint, exits 75, is requeued and resumes.
stop_and_resume() {
  local name=$1 signal=$2 how=$3
  local manifest batch array done_rows resumed
  manifest=$("$repo/target/debug/examples/tiny_batch" "$work/inputs-$name" 600)
  batch="$work/batch-$name"
  "$bin" batch plan "$manifest" --out "$batch"
  "$bin" batch slurm "$batch" --partition smoke --gpus 0 --cpus 1 --memory-gb 1 --time 00:10:00 --parallel 2
  array=$(sbatch --parsable "$batch/batch.sbatch")
  for _ in $(seq 600); do
    ls "$batch"/*/checkpoint/state.json >/dev/null 2>&1 && break
    sleep 0.1
  done
  # A task that has only just started cannot be signalled yet ("try again later").
  for _ in $(seq 50); do
    scancel --signal="$signal" "$how" "$array" 2>/dev/null && break
    sleep 0.2
  done
  echo "sent $signal ($how) to the running tasks of array $array"
  for _ in $(seq 300); do
    [ -z "$(squeue -h -j "$array" 2>/dev/null)" ] && break
    sleep 1
  done
  "$bin" batch status "$batch"
  "$bin" batch collect "$batch"
  done_rows=$(tail -n +2 "$batch/results.csv" | grep -c ',done,' || true)
  resumed=$(grep -l resuming "$batch"/logs/*.out | wc -l)
  echo "$name: results.csv: $done_rows of 4 jobs done; $resumed task(s) resumed after $signal"
  grep -h -e resuming -e stopping -e interrupted "$batch"/logs/*.out || true
  [ "$done_rows" -eq 4 ] && [ "$resumed" -ge 1 ]
}
stop_and_resume time-limit USR1 --batch
stop_and_resume cancel TERM --full
echo "slurm smoke: passed"
