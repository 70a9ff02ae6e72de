#!/usr/bin/env bash
# The ROS 2 bridge's DDS tests (ros2-bridge/tests/dds.rs), inside a private network
# namespace that this script creates with `unshare -n` and that ends with it: DDS discovery
# multicasts, and nothing may leave the machine. Inside, only `lo` exists, with multicast
# on and a route for 224.0.0.0/4. Needs root; skips (exit 0, saying why) without it.
# Installs the PyPI package cyclonedds (the independent DDS stack of the interop test)
# when it is missing.
set -euo pipefail
cd "$(dirname "$0")/../.."

script=dds.sh
. tests/scripts/netns.sh
[ "$(id -u)" = 0 ] || skip "needs root (for unshare -n)"
need unshare "unshare (util-linux)"
need ip "iproute2 (ip)"
need python3 python3
unshare -n true 2>/dev/null || skip "cannot create a network namespace (unshare -n)"

if ! python3 -c "import cyclonedds" 2>/dev/null; then
  python3 -m pip install -q cyclonedds || pip install -q --break-system-packages cyclonedds
fi

# Build outside the namespace (cargo may want the registry); run offline inside it.
cargo build -q -p sim-host
cargo test -q -p armctl-ros2 --test dds --no-run
# Absolute: the test runs in ros2-bridge/ (cargo test's working directory is the package's).
target_dir=$(realpath "${CARGO_TARGET_DIR:-target}")
export SIM_HOST_BIN="$target_dir/debug/sim-host"

unshare -n -- bash -c '
  set -euo pipefail
  script=dds.sh
  . tests/scripts/netns.sh
  lo_multicast
  ARMCTL_ROS2_NETNS=1 timeout 900 cargo test -q --offline -p armctl-ros2 --test dds -- \
    --ignored --test-threads=1 --nocapture
'
