#!/usr/bin/env bash
# The closed loop on the simulated rig, then the rollout judged like a demonstration.
#
#   examples/closed_loop.sh [OUT]          (default OUT: closed_loop_out; run from the repository root)
#
# 1. The policy's features: a short scripted demonstration of the rig (`sim --bag`), replayed into an ROI bag
#    and exported as a LeRobot dataset; `policy run` reads its camera keys, state and action names and fps.
# 2. The loop, each a process of its own on loopback DDS: the live node (with command_topic, so every frame
#    also records the command residual), the recorder (the node's metadata and global view, the joint states and
#    the commands), `policy run` with
#    examples/hold_pose_policy.py (one fixed pose, commands at the dataset's fps), and the simulated rig
#    following those commands (`sim --follow-commands`, joints at most --max-joint-speed-rad-s).
# 3. `roi-node validate` of the recording: the usual gates plus the rollout's (policy-driven spans, ROI jitter
#    there, recovery after out-of-frame excursions); the report is in OUT/report/REPORT.md.
#
# Environment: RIG (default config/rig_demo_bimanual.yaml), DURATION_S (20), RATE_HZ (30), SPEED_RAD_S (1.0),
# ROS_DOMAIN_ID (42; loopback only), ROI_NODE (the roi-node command; default .venv/bin/roi-node, else roi-node).
# Exit status: validate's (0 every gate passes, 1 a gate fails, 2 unusable input), or the failing step's.
set -euo pipefail

OUT=${1:-closed_loop_out}
RIG=${RIG:-config/rig_demo_bimanual.yaml}
DURATION_S=${DURATION_S:-20}
RATE_HZ=${RATE_HZ:-30}
SPEED_RAD_S=${SPEED_RAD_S:-1.0}
COMMANDS=/joint_commands
if [[ -z ${ROI_NODE:-} ]]; then
    if [[ -x .venv/bin/roi-node ]]; then ROI_NODE=.venv/bin/roi-node; else ROI_NODE=roi-node; fi
fi
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST ROS_DOMAIN_ID=${ROS_DOMAIN_ID:-42}

if [[ -e $OUT ]]; then
    echo "closed_loop.sh: $OUT exists; remove it or name another folder" >&2
    exit 2
fi
mkdir -p "$OUT/logs"
LOGS=$OUT/logs

started=()  # the process ids this script started: stopped on any exit, by id
stop() {  # SIGINT (a clean stop with a summary line), then wait for it
    local pid=$1
    if kill -0 "$pid" 2>/dev/null; then
        kill -INT "$pid" 2>/dev/null || true
        for _ in $(seq 100); do kill -0 "$pid" 2>/dev/null || break; sleep 0.2; done
        kill -0 "$pid" 2>/dev/null && kill -KILL "$pid" 2>/dev/null || true
    fi
    wait "$pid" 2>/dev/null || true
}
cleanup() {
    for pid in "${started[@]}"; do stop "$pid"; done
}
trap cleanup EXIT

echo "closed loop: rig $RIG, $DURATION_S s at $RATE_HZ Hz, ROS_DOMAIN_ID=$ROS_DOMAIN_ID -> $OUT/"
echo "1/3 the policy's features: a 2 s scripted demonstration, replayed and exported"
"$ROI_NODE" sim --config "$RIG" --bag "$OUT/demonstration" --duration 2 --rate-hz "$RATE_HZ" --seed 1 >"$LOGS/demonstration.log" 2>&1
"$ROI_NODE" replay "$OUT/demonstration" -o "$OUT/demonstration_roi" --config "$RIG" >>"$LOGS/demonstration.log" 2>&1
"$ROI_NODE" export lerobot "$OUT/demonstration_roi" -o "$OUT/dataset" --fps "$RATE_HZ" --task "hold the pose" \
    >>"$LOGS/demonstration.log" 2>&1

echo "2/3 the loop: node, recorder, policy, simulated rig following $COMMANDS"
"$ROI_NODE" run --config "$RIG" --ros-args -p "command_topic:=$COMMANDS" -p qos.subscription_reliability:=reliable \
    >"$LOGS/node.log" 2>&1 &
node=$!; started+=("$node")
# what validate reads (the metadata), the commands and the joint states it judges them by, and the global view for the
# report's contact sheet; not the full-size camera stream
"$ROI_NODE" record -o "$OUT/rollout" --topics roi/metadata roi/global/image_raw joint_states "$COMMANDS" \
    >"$LOGS/record.log" 2>&1 &
recorder=$!; started+=("$recorder")
"$ROI_NODE" policy run --policy examples.hold_pose_policy:hold_pose --features "$OUT/dataset" --config "$RIG" \
    --command-topic "$COMMANDS" --timeout-s 120 >"$LOGS/policy.log" 2>&1 &
policy=$!; started+=("$policy")
# the rig starts its clock once the node subscribes to its camera and joint states; a recording run wants every
# frame, so a frame rendered late is sent late (its lateness in the sim's last line) rather than dropped
"$ROI_NODE" sim live --config "$RIG" --duration "$DURATION_S" --rate-hz "$RATE_HZ" --min-subscribers 1 \
    --follow-commands "$COMMANDS" --max-joint-speed-rad-s "$SPEED_RAD_S" --late-frames send >"$LOGS/sim.log" 2>&1
tail -n 2 "$LOGS/sim.log"
for pid in "$policy" "$recorder" "$node"; do stop "$pid"; done  # the policy first, the node last: the recorder sees the end
started=()
tail -n 1 "$LOGS/policy.log"

echo "3/3 validating the rollout"
status=0
"$ROI_NODE" validate "$OUT/rollout" --command-topic "$COMMANDS" --report "$OUT/report" || status=$?
exit "$status"
