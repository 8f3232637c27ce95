#!/usr/bin/env bash
# Issue 50's case, N times: `nbvdata generate --backend dask --scheduler ADDR` into a new folder with two
# `dask worker --nthreads 1` processes (as docs/generating.md shows), one of them SIGKILLed DELAY seconds
# into the job (its units are then redone by the other worker), and the README's dataset verified
# against its published manifest byte for byte. Prints one line per trial and exits 1 if any differs.
#
#   benchmarks/worker_kill.sh [TRIALS=10] [DELAYS="3 4 5 6"] [MANIFEST=manifests/builtin-shapes-1.3.0.json]
#
# Run from the repository root with the package installed (the dask extra). Uses ports 18700-18799 on
# 127.0.0.1 and folders under ${TMPDIR:-/tmp}/nbv-worker-kill.
set -uo pipefail

TRIALS=${1:-10}
DELAYS=(${2:-3 4 5 6})
MANIFEST=${3:-manifests/builtin-shapes-1.3.0.json}
ROOT=${TMPDIR:-/tmp}/nbv-worker-kill
mkdir -p "$ROOT"
failed=0
for trial in $(seq 1 "$TRIALS"); do
    delay=${DELAYS[$(( (trial - 1) % ${#DELAYS[@]} ))]}
    port=$((18700 + trial % 100))
    out=$ROOT/out-$trial
    rm -rf "$out"
    dask scheduler --port "$port" --no-dashboard >"$ROOT/scheduler-$trial.log" 2>&1 &
    scheduler=$!
    sleep 4
    dask worker "tcp://127.0.0.1:$port" --nthreads 1 --no-dashboard >"$ROOT/worker-a-$trial.log" 2>&1 &
    victim=$!
    dask worker "tcp://127.0.0.1:$port" --nthreads 1 --no-dashboard >"$ROOT/worker-b-$trial.log" 2>&1 &
    survivor=$!
    sleep 6
    nbvdata generate --out "$out" --backend dask --scheduler "tcp://127.0.0.1:$port" --no-progress \
        >"$ROOT/generate-$trial.log" 2>&1 &
    job=$!
    sleep "$delay"
    pkill -KILL -P "$victim" 2>/dev/null
    kill -KILL "$victim" 2>/dev/null
    wait "$job"
    status=$?
    verdict=$(nbvdata verify "$MANIFEST" --root "$out" 2>&1 | tail -1)
    echo "trial $trial: worker killed ${delay} s into the job; generate exit $status; $verdict"
    case "$verdict" in ok:*) ;; *) failed=1 ;; esac
    kill "$survivor" "$scheduler" 2>/dev/null
    wait 2>/dev/null
done
exit $failed
