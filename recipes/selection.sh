#!/usr/bin/env bash
# Issue 27's recipe, stage by stage (docs/selection.md): the data (the 150 shared train meshes and the
# 999 usable procedural objects of ../shared/meshes/extra, 14 runs each, exploration 0.25), its
# publication as train-meshes 1.2.0 (no test part: the test objects are ../shared/meshes/test), each
# network fitted in sittings (fit --resume: bit-exact) with a snapshot evaluated in closed loop on the
# version's validation objects after every sitting, the ideas measured on the same objects, and the
# one evaluation of the test objects at the end. Every choice reads validation objects only.
#
#   recipes/selection.sh data                  # generate (resumable: run it again after a kill)
#   recipes/selection.sh publish               # manifests/train-meshes-1.2.0.json, then verify it
#   recipes/selection.sh fit NET               # one sitting of NET: scores-fc3, scores-fc3-wide (twice as
#                                                 # wide, scores-dagger's states added), scores-3, regression or
#                                                 # regression-near-best (nbvnet-4-3 on the near-best loss);
#                                                 # run it again until it says the validation stopped improving
#   recipes/selection.sh dagger [N]            # DAgger round N (1): the policy's runs on the training
#                                                 # meshes, every state labelled exactly; then fit regression-dagger
#                                                 # (round 1) or regression-daggerN: near-best, started from the
#                                                 # round's policy, rounds 1..N added. The policy of round N is the
#                                                 # best snapshot on the validation objects of the run before it
#                                                 # (regression-near-best, regression-dagger, regression-dagger2...);
#                                                 # fit regression-scans: nbvnet-4-3-scans (told where the sensor
#                                                 # has been) from round 1's policy widened, on train + round 1
#   recipes/selection.sh scans-dagger          # regression-scans' own round (round 2, seed 2, as dagger 2):
#                                                 # rolled by its best snapshot; then fit regression-scans2 (that
#                                                 # snapshot on train + round 1 + this round), the control being
#                                                 # dagger 2 and fit regression-dagger2
#   recipes/selection.sh scores-dagger         # the released score network's own runs on the training meshes
#                                                 # (6 each, seed 11), every state labelled exactly: the data
#                                                 # scores-fc3-wide adds; fit scores-fc3-dagger fine-tunes the
#                                                 # round's policy on the training part plus the round
#   recipes/selection.sh select                # the ideas on the validation objects, and the table
#   FINAL_SCORES=... FINAL_REGRESSION=... recipes/selection.sh test   # once: the shared test objects
#   recipes/selection.sh table                 # every validation result so far, as one table
#   SMOKE=1 recipes/selection.sh all           # every stage at a tiny budget (4 meshes, the smoke
#                                                 # scene, 1 epoch a sitting) into runs/smoke-selection
#
# Run from the repository root with the package installed. Settings (environment): WORKERS (evaluate and
# generate processes, 2), THREADS (torch threads of fit, 1), EPOCHS_PER_SITTING (2; SMOKE 1), PATIENCE
# (sittings without a new best before a network counts as converged, 3; SMOKE 1), SELECT_BY (the mean that
# ranks: shared, all or procedural; default shared), OUT (runs/selection), MESHES (../shared/meshes),
# DAGGER_POLICY (the checkpoint that rolls a DAgger round and starts its fine-tuning; default: the best).
set -euo pipefail

SMOKE=${SMOKE:-0}
MESHES=${MESHES:-../shared/meshes}
WORKERS=${WORKERS:-2}
THREADS=${THREADS:-1}
SELECT_BY=${SELECT_BY:-shared}
VERSION=1.2.0
if [ "$SMOKE" = 1 ]; then
    OUT=${OUT:-runs/smoke-selection}
    EPOCHS_PER_SITTING=${EPOCHS_PER_SITTING:-1}
    PATIENCE=${PATIENCE:-1}
    NAME=selection-smoke
    DATA=$OUT/data
    MANIFESTS=$OUT/manifests
    LIST=$OUT/meshes.txt
    TEST_MESHES=$OUT/test-meshes.txt
    SCENE=(--config configs/smoke.yaml)             # generate, evaluate: the tiny scene of the tests
    CLOUDS=()
    EVAL=(--scans 3 --random-starts 0 --seed 1)
    BATCH=(--batch-size 16)
else
    OUT=${OUT:-runs/selection}
    EPOCHS_PER_SITTING=${EPOCHS_PER_SITTING:-2}
    PATIENCE=${PATIENCE:-3}
    NAME=train-meshes
    DATA=data/train-meshes-$VERSION
    MANIFESTS=manifests
    LIST=configs/train-meshes-$VERSION.txt
    TEST_MESHES=$MESHES/test/
    SCENE=()                                        # the default (fitted) scene, as train-meshes 1.1.0
    CLOUDS=(--set state.points=1024)                # every state's cloud too, as the published version
    EVAL=(--scans 10 --random-starts 2 --seed 1)    # as the released models' card
    BATCH=(--batch-size 64)
fi
MANIFEST=$MANIFESTS/$NAME-$VERSION.json
VAL=$OUT/val                                        # one folder per evaluation on the validation objects
log() { printf '\n== %s\n' "$*" >&2; }

smoke_lists() {  # 2 shared train meshes and 2 procedural objects; 2 test objects
    mkdir -p "$OUT"
    local root
    root=$(cd "$MESHES" && pwd)
    printf '%s\n' "$root/train/milk__robosuite.stl" "$root/train/bread__robosuite.stl" \
        "$root/extra/pybullet_random_urdfs/random_400.obj" "$root/extra/pybullet_random_urdfs/random_401.obj" > "$LIST"
    printf '%s\n' "$root/test/sphere__trimesh.stl" "$root/test/teapot__alecjacobson.obj" > "$TEST_MESHES"
}

stage_data() {
    [ "$SMOKE" = 1 ] && smoke_lists
    log "generate: $LIST -> $DATA"
    nice -n 10 nbvdata generate --meshes "$LIST" --out "$DATA" --runs-per-mesh 14 --explore 0.25 \
        --workers "$WORKERS" "${SCENE[@]}" "${CLOUDS[@]}"
}

stage_publish() {
    log "publish $NAME $VERSION"
    nbvdata publish "$DATA" --name "$NAME" --version "$VERSION" --manifests "$MANIFESTS" --meshes "$MESHES" \
        --about manifests/about.yaml \
        --test-fraction 0 --notes "Issue 27's data: the 150 shared train meshes and the 999 usable procedural \
objects of ../shared/meshes/extra/pybullet_random_urdfs (random_000-999 but random_168: NaN vertices), 14 runs \
each from random start views, exploration epsilon 0.25, default (fitted) scene; its validation meshes choose \
every setting (recipes/selection.sh). Made with: nbvdata generate --meshes configs/train-meshes-1.2.0.txt \
--out data/train-meshes-1.2.0 --runs-per-mesh 14 --explore 0.25"
    nbvdata verify "$MANIFEST"
}

# DAgger round N: its shards, the run whose best validation snapshot rolls it, the run that fine-tunes on it
dagger_data() { echo "$DATA-dagger$1"; }
dagger_run() { [ "$1" = 1 ] && echo regression-dagger || echo "regression-dagger$1"; }
dagger_round() { local n=${1#regression-dagger}; echo "${n:-1}"; }
policy_run() { [ "$1" = 1 ] && echo regression-near-best || dagger_run $(( $1 - 1 )); }
# DAGGER_POLICY overrides the choice (round 1 was rolled by regression-near-best's epoch 5, its best)
dagger_policy() { [ -n "${DAGGER_POLICY:-}" ] && echo "$DAGGER_POLICY" || best "$(policy_run "$1")"; }

stage_dagger() {  # N: 4 runs per training mesh from other start views (seed N), every move the policy's
    local round=${1:-1} policy data
    policy=$(dagger_policy "$round")
    data=$(dagger_data "$round")
    log "DAgger round $round: $policy on the training part of $NAME $VERSION -> $data"
    nice -n 5 nbvdata generate --manifest "$MANIFEST" --part train --meshes "$MESHES" --policy "$policy" \
        --runs-per-mesh 4 --seed "$round" --workers "$WORKERS" --out "$data" "${SCENE[@]}" "${CLOUDS[@]}" --no-progress
}

# The score network's round: the released nbvscore-fc3 (scores-fc3's best snapshot, epoch 14; with SMOKE the
# smoke run's best, the released one being for the default scene; or DAGGER_POLICY) drives 6 runs from other
# start views (seed 11) on each training mesh, every state labelled exactly; its moves are candidate views,
# so the view state stays known (a score network can train on it). No clouds: the grid networks read none.
SCORES_DAGGER=$DATA-scores-dagger1
scores_dagger_policy() {  # DAGGER_POLICY, the smoke run's best scores-fc3, or the released score network
    if [ -n "${DAGGER_POLICY:-}" ]; then echo "$DAGGER_POLICY"
    elif [ "$SMOKE" = 1 ]; then best scores-fc3
    else echo nbvtrain/released/nbvscore-fc3.pt; fi
}

stage_scores_dagger() {
    local policy
    policy=$(scores_dagger_policy)
    log "the score network's round: $policy on the training part of $NAME $VERSION -> $SCORES_DAGGER"
    nice -n 5 nbvdata generate --manifest "$MANIFEST" --part train --meshes "$MESHES" --policy "$policy" \
        --runs-per-mesh 6 --seed 11 --workers "$WORKERS" --out "$SCORES_DAGGER" "${SCENE[@]}" --no-progress
}

# regression-scans' own round: its best snapshot (or DAGGER_POLICY) rolls round 2 from the start views of
# dagger 2 (seed 2), so that regression-dagger2 on dagger 2 is its control
SCANS_DAGGER=$DATA-scans-dagger2
scans_dagger_policy() { [ -n "${DAGGER_POLICY:-}" ] && echo "$DAGGER_POLICY" || best regression-scans; }

stage_scans_dagger() {
    local policy
    policy=$(scans_dagger_policy)
    log "regression-scans' round: $policy on the training part of $NAME $VERSION -> $SCANS_DAGGER"
    nice -n 5 nbvdata generate --manifest "$MANIFEST" --part train --meshes "$MESHES" --policy "$policy" \
        --runs-per-mesh 4 --seed 2 --workers "$WORKERS" --out "$SCANS_DAGGER" "${SCENE[@]}" "${CLOUDS[@]}" --no-progress
}

rolled_by() {  # POLICY DATA [STAGE]: exit 2 unless DATA is a round POLICY rolled (policy.yaml's sha256)
    if [ ! -f "$2/policy.yaml" ]; then
        echo "selection.sh: $2 holds no round: run recipes/selection.sh ${3:-dagger} first" >&2
        exit 2
    elif [ "$(sha256sum < "$1" | cut -d' ' -f1)" != "$(sed -n 's/^sha256: //p' "$2/policy.yaml")" ]; then
        echo "selection.sh: $1 did not roll $2 (policy.yaml); set DAGGER_POLICY to the checkpoint that did" >&2
        exit 2
    fi
}

dagger_flags() {  # N -> --add-train of rounds 1..N and --init the policy of round N (its sha256 checked)
    local round=$1 policy data i flags=""
    policy=$(dagger_policy "$round")
    data=$(dagger_data "$round")
    rolled_by "$policy" "$data" "dagger $round"
    for i in $(seq 1 "$round"); do flags="$flags --add-train $(dagger_data "$i")"; done
    echo "$flags --init $policy"
}

fit_flags() {  # NET -> the fit settings of its first sitting (constant lr: a run extended is the same run)
    case $1 in
        scores-fc3) echo "--model nbvscore-fc3 --score-loss regression --lr 1e-3 --dropout-from fc1 --dropout 0.3" ;;
        scores-3) echo "--model nbvscore-3 --score-loss regression --augment --lr 1e-3 --dropout-from fc1 --dropout 0.3" ;;
        # issue 27's "larger nbvscore-fc3 with more data": twice as wide, the score network's own round
        # added (scores-dagger; a regression round's states have no view state a score network can read)
        scores-fc3-wide)
            if [ ! -f "$SCORES_DAGGER/policy.yaml" ]; then
                echo "selection.sh: scores-fc3-wide adds $SCORES_DAGGER: run recipes/selection.sh scores-dagger first" >&2
                exit 2
            fi
            echo "$(fit_flags scores-fc3 | sed 's/nbvscore-fc3/nbvscore-fc3-wide/') --add-train $SCORES_DAGGER" ;;
        scores-fc3-dagger)  # the policy of the score network's round, fine-tuned on the training part + the round
            local policy
            policy=$(scores_dagger_policy)
            rolled_by "$policy" "$SCORES_DAGGER" scores-dagger
            echo "$(fit_flags scores-fc3) --add-train $SCORES_DAGGER --init $policy" ;;
        regression) echo "--model nbvnet-4-3 --lr 3e-4 --augment" ;;
        # the same network, learning from the near-best views instead of the label (nbvtrain/networks/scores.py)
        regression-near-best) echo "--model nbvnet-4-3 --lr 3e-4 --augment --regression-loss near-best --near-best 0.9" ;;
        regression-dagger|regression-dagger[0-9]*)
            local round extra
            round=$(dagger_round "$1")
            extra=$(dagger_flags "$round") || exit 2
            echo "$(fit_flags regression-near-best) $extra" ;;
        # the same network told where the sensor has been (nbvnet-4-3-scans), started from round 1's
        # policy widened (its new inputs' weights zero: the same network at first) on the training part + round 1
        regression-scans)
            local extra
            extra=$(dagger_flags 1) || exit 2
            echo "$(fit_flags regression-near-best | sed 's/nbvnet-4-3 /nbvnet-4-3-scans /') $extra" ;;
        # regression-scans' round added: its policy on the training part + round 1 + its own round
        regression-scans2)
            local policy
            policy=$(scans_dagger_policy)
            rolled_by "$policy" "$SCANS_DAGGER" scans-dagger
            echo "$(fit_flags regression-near-best | sed 's/nbvnet-4-3 /nbvnet-4-3-scans /') --add-train $(dagger_data 1)" \
                "--add-train $SCANS_DAGGER --init $policy" ;;
        *) echo "unknown network $1: scores-fc3, scores-fc3-wide, scores-fc3-dagger, scores-3, regression, regression-near-best, regression-dagger[N], regression-scans or regression-scans2" >&2
           exit 2 ;;
    esac
}

planner_of() { case $1 in regression*) echo "regression --checkpoint" ;; *) echo "scores --score-checkpoint" ;; esac; }

epochs_done() { [ -f "$1/metrics.csv" ] && echo $(( $(wc -l < "$1/metrics.csv") - 1 )) || echo 0; }

evaluate_val() {  # OUT_NAME EVALUATE_FLAGS...: one closed-loop evaluation of the validation objects
    local out=$VAL/$1
    shift
    [ -f "$out/coverage.csv" ] && return 0             # done before: evaluations are deterministic
    log "validation objects: $out"
    rm -rf "$out"
    nice -n 10 nbvtrain evaluate --manifest "$MANIFEST" --part val --meshes "$MESHES" "${EVAL[@]}" \
        --workers "$WORKERS" "${SCENE[@]}" --out "$out" --no-progress --no-floors "$@"
}

stage_fit() {
    local net=$1 run=$OUT/fit/$1 done target planner flag snapshot flags
    read -r planner flag <<< "$(planner_of "$net")"
    mkdir -p "$run/snapshots"
    done=$(epochs_done "$run")
    snapshot=$run/snapshots/epoch-$(printf %03d "$done").pt
    if [ "$done" -gt 0 ] && [ $(( done % EPOCHS_PER_SITTING )) -eq 0 ] && [ ! -f "$snapshot" ]; then
        cp "$run/last.pt" "$snapshot"                   # a sitting whose snapshot was not taken yet
    elif converged "$net"; then
        log "$net: no new best on the validation objects in the last $PATIENCE sittings: converged"
        table "$VAL/$net-e"*
        return 0
    else
        target=$(( (done / EPOCHS_PER_SITTING + 1) * EPOCHS_PER_SITTING ))
        log "$net: sitting to epoch $target (Ctrl-C saves; run this again to resume)"
        if [ -f "$run/config.yaml" ]; then
            nice -n 10 nbvtrain fit --resume --out "$run" --epochs "$target" --no-progress
        else
            flags=$(fit_flags "$net")                   # an assignment: its refusal stops the script
            # shellcheck disable=SC2086
            nice -n 10 nbvtrain fit "$MANIFEST" --split mesh $flags "${BATCH[@]}" --epochs "$target" \
                --threads "$THREADS" --out "$run" --no-progress
        fi
        snapshot=$run/snapshots/epoch-$(printf %03d "$target").pt
        cp "$run/last.pt" "$snapshot"
    fi
    for snapshot in "$run"/snapshots/epoch-*.pt; do    # every snapshot not evaluated yet (after a kill too)
        local epoch=${snapshot##*/epoch-}
        evaluate_val "$net-e${epoch%.pt}" --planners "$planner" "$flag" "$snapshot"
    done
    table "$VAL/$net-e"*
    converged "$net" && log "$net: converged (no new best in the last $PATIENCE sittings)" || true
}

converged() { [ -n "$(ls -d "$VAL/$1-e"* 2>/dev/null)" ] && python recipes/selection_table.py --by "$SELECT_BY" \
    --stopped "$PATIENCE" "$VAL/$1-e"*; }

best() { python recipes/selection_table.py --by "$SELECT_BY" --top 1 "$VAL/$1-e"*; }

table() { python recipes/selection_table.py --by "$SELECT_BY" "$@"; }

stage_select() {
    local fc3 three regression top
    fc3=$(best scores-fc3)
    three=$(best scores-3)
    regression=$(best regression)
    log "best snapshots on the validation objects: $fc3, $three, $regression"
    evaluate_val baselines --planners infogain,oracle,random,farthest
    evaluate_val regression-nostall --planners regression --checkpoint "$regression" --no-stall
    evaluate_val regression-tta --planners regression --checkpoint "$regression" --tta
    evaluate_val regression-spread1 --planners regression --checkpoint "$regression" --spread 1
    evaluate_val regression-spread2 --planners regression --checkpoint "$regression" --spread 2
    evaluate_val scores-3-tta --planners scores --score-checkpoint "$three" --tta
    evaluate_val ensemble-fc3-3 --planners scores --score-checkpoint "$fc3,$three"
    # the three best snapshots of nbvscore-3 as an ensemble (no more training)
    top=$(table --top 3 "$VAL"/scores-3-e*)
    evaluate_val ensemble-scores-3-snapshots --planners scores --score-checkpoint "$top"
    # the hybrid on the better score network; weights 0.25..2 in one run (one scene build per object)
    local winner
    winner=$(table --top 1 "$VAL"/scores-fc3-e* "$VAL"/scores-3-e*)
    evaluate_val hybrid --planners hybrid --score-checkpoint "$winner" --hybrid-weight 0.25,0.5,1,2
    table "$VAL"/*
}

stage_test() {
    if [ -e "$OUT/test" ]; then
        echo "selection.sh test: $OUT/test exists: the test objects are evaluated once, at the end" >&2
        exit 2
    fi
    : "${FINAL_SCORES:?set FINAL_SCORES to the score checkpoint(s) the validation objects chose (comma-separated: an ensemble)}"
    : "${FINAL_REGRESSION:?set FINAL_REGRESSION to the regression checkpoint the validation objects chose}"
    local planners=${FINAL_PLANNERS:-scores,regression,infogain,oracle,random,farthest}
    log "the test objects, once: $TEST_MESHES"
    # shellcheck disable=SC2086
    nice -n 10 nbvtrain evaluate --meshes "$TEST_MESHES" --planners "$planners" --score-checkpoint "$FINAL_SCORES" \
        --checkpoint "$FINAL_REGRESSION" ${FINAL_FLAGS:-} "${EVAL[@]}" --workers "$WORKERS" "${SCENE[@]}" \
        --out "$OUT/test" --no-progress
    table "$OUT/test"
}

case ${1:-} in
    data) stage_data ;;
    publish) stage_publish ;;
    fit) stage_fit "${2:?fit NET: scores-fc3, scores-fc3-wide, scores-fc3-dagger, scores-3, regression, regression-near-best, regression-dagger[N], regression-scans or regression-scans2}" ;;
    dagger) stage_dagger "${2:-1}" ;;
    scores-dagger) stage_scores_dagger ;;
    scans-dagger) stage_scans_dagger ;;
    select) stage_select ;;
    test) stage_test ;;
    table) table "$VAL"/* ;;
    all)
        [ "$SMOKE" = 1 ] || { echo "selection.sh all: only with SMOKE=1 (the real stages take days)" >&2; exit 2; }
        rm -rf "$OUT"
        stage_data
        stage_publish
        for net in scores-fc3 scores-3 regression; do stage_fit $net; done
        stage_fit scores-3                            # a second sitting: fit --resume to epoch 2
        stage_scores_dagger                           # rolled by scores-fc3's best snapshot
        stage_fit scores-fc3-wide
        stage_fit scores-fc3-dagger
        stage_fit regression-near-best
        stage_dagger 1
        stage_fit regression-dagger
        stage_fit regression-scans
        stage_scans_dagger                            # rolled by regression-scans' best snapshot
        stage_fit regression-scans2
        stage_dagger 2                                # rolled by regression-dagger's best snapshot
        stage_fit regression-dagger2
        stage_select
        FINAL_SCORES=$(table --top 1 "$VAL"/scores-*-e*) FINAL_REGRESSION=$(best regression) stage_test ;;
    *) sed -n '2,/^set -euo/{/^set/!p;}' "$0" >&2; exit 2 ;;
esac
