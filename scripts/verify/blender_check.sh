#!/usr/bin/env bash
# Blender imports `imuflow export`'s BVH and glb of the bundled sample's true motion
# (models/sample/walk.mcap, channel source.truth) and of a lower-body set's estimate (the
# lower-body example, whose exports hold the five joints the set observes) and moves the body as
# imuflow does: every written joint's world position and rotation at several frames within 5 mm
# and 0.5 degrees of imuflow's forward kinematics (scripts/verify/blender_check.py), and one frame
# of each rendered with Workbench.
#
#   scripts/verify/blender_check.sh [OUT_DIR]        # default out/blender-check
#
# Uses target/release/imuflow, else target/debug/imuflow (or IMUFLOW_BIN), and the fk_reference
# example of tools/export built with the same profile. Without Blender it says so and exits 0.
set -euo pipefail
cd "$(dirname "$0")/../.."
out="${1:-out/blender-check}"

if ! command -v blender >/dev/null 2>&1; then
    echo "blender_check: SKIPPED: no 'blender' on PATH, so the exports were not checked in Blender."
    echo "blender_check: to run it: apt-get install -y blender python3-numpy (Debian's Blender 3.4 works), then $0"
    exit 0
fi

profile=""
if [ -n "${IMUFLOW_BIN:-}" ]; then
    bin="$IMUFLOW_BIN"
elif [ -x target/release/imuflow ]; then
    bin=target/release/imuflow
    profile=--release
elif [ -x target/debug/imuflow ]; then
    bin=target/debug/imuflow
else
    echo "blender_check: no imuflow binary: build it first (cargo build --release) or set IMUFLOW_BIN" >&2
    exit 2
fi

# The export keeps 779 of the sample's frames (models/sample/README.md): its first and last, and
# frames through the walk; the middle one is rendered.
frames=(0 97 251 389 517 650 778)
mkdir -p "$out"

# check NAME RECORDING CHANNEL: exports the channel as BVH and glb, writes imuflow's forward
# kinematics of the joints the export writes, and has Blender compare its imports with them.
check() {
    local name="$1" recording="$2" channel="$3"
    "$bin" export "$recording" --channel "$channel" --format bvh -o "$out/$name.bvh"
    "$bin" export "$recording" --channel "$channel" --format glb -o "$out/$name.glb"
    # shellcheck disable=SC2086
    cargo run --quiet $profile -p imuflow-export --example fk_reference -- \
        "$recording" "$channel" "${frames[@]}" >"$out/$name.expected.json"
    local start status=0
    start=$(date +%s)
    blender -b --factory-startup --python scripts/verify/blender_check.py -- \
        "$out/$name.bvh" "$out/$name.glb" "$out/$name.expected.json" "$out/$name.png" \
        >"$out/$name.blender.log" 2>&1 || status=$?
    grep '^blender_check:' "$out/$name.blender.log" || true
    echo "blender_check: Blender ran $(( $(date +%s) - start )) s; its log: $out/$name.blender.log"
    if [ "$status" -ne 0 ] || ! grep -q '^blender_check: rendered' "$out/$name.blender.log"; then
        echo "blender_check: FAILED (Blender exit status $status); the log's end:" >&2
        tail -n 30 "$out/$name.blender.log" >&2
        exit 1
    fi
}

# The sample's true motion: every joint.
check truth models/sample/walk.mcap source.truth
# A lower-body set's estimate (configs/examples/lower-body.toml, its sensed bones): the five
# joints it observes, the shanks ending at the ankles.
"$bin" run configs/examples/lower-body.toml --no-progress --quiet \
    --set "stages.record.params.path=$out/lower-body.mcap" --without viz >"$out/lower-body.run.log" 2>&1 \
    || { echo "blender_check: the lower-body example failed; its log: $out/lower-body.run.log" >&2; exit 1; }
check lower-body "$out/lower-body.mcap" opt.motion
