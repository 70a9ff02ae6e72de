#!/usr/bin/env bash
# What the board's own code costs, counted on the `cargo fw` ELF itself on Renode (issue 34):
# instructions per step of the step path's interrupts at 100 kHz (1 joint, 8 in step, 8 at
# distinct rates) with where they go per function, and every span firmware-wide that masks
# the DIR interrupt (TIM13) during a run with a flood and 1 kHz LOCATION reports, with the
# code that opened it, and DIR's lateness at each change. See README.md.
#
# It builds nothing of its own: it runs tests/tests/renode_cost.rs, which boots the ELF on
# Renode with the step path's models (tests/renode/step-path.resc) and a CPU probe
# (tests/renode/CostProbe.cs) that counts every block the CPU executes in the exception
# that runs it. That test file also fails if a copy of the board's step path appears
# under scripts/ again (the former QEMU harness, src/board.rs, was one).
#
# Needs Renode (RENODE, default ../shared/renode/renode beside the repository, or `renode`
# on PATH; mono) and root (the board's network namespace). Figures are printed, never gated
# on speed. Usage: run.sh
set -euo pipefail

here="$(cd "$(dirname "$0")" && pwd)"
root="$(cd "$here/../.." && pwd)"
cd "$root"
if [ -z "${RENODE:-}" ] && ! command -v renode >/dev/null && [ -x "$root/../shared/renode/renode" ]; then
  export RENODE="$root/../shared/renode/renode"
fi

out="$(mktemp)"
trap 'rm -f "$out"' EXIT
if ! cargo test --quiet -p system-tests --test renode_cost -- --nocapture --test-threads=1 >"$out" 2>&1; then
  cat "$out" >&2
  echo "step-cost: tests/tests/renode_cost.rs failed" >&2
  exit 1
fi
# The figures (each test prints them as "renode cost: ..." lines); none means a skip.
grep '^renode cost: ' "$out" | sed 's/^renode cost: //' || true
if ! grep -q 'instructions per step (goal' "$out" || ! grep -q '^renode cost: longest: ' "$out"; then
  grep -i 'renode\|root' "$out" >&2 || true
  echo "step-cost: no figures (Renode or root missing?): see above" >&2
  exit 1
fi
