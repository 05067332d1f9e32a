#!/usr/bin/env bash
# Env steps/s of a process-mode run resumed from RUN_DIR's newest checkpoint with φ rounds in
# line (the default), then with `encoder.background_rounds = true`: SECS seconds each, one after
# the other, on a fresh copy of RUN_DIR each time (RUN_DIR itself is not touched; the copies
# are removed). Rates over the launch's metrics lines from 60 s after its first ingest.
#   scripts/bench_phi_rounds.sh RUN_DIR [SECS=420] [OUT=bench-phi-rounds]
set -euo pipefail
run_dir=${1:?usage: scripts/bench_phi_rounds.sh RUN_DIR [SECS] [OUT]}
secs=${2:-420}
out=${3:-bench-phi-rounds}
asi=${ASI_BIN:-target/release/asi}
[ -x "$asi" ] || cargo build --release --locked
mkdir -p "$out"
for mode in in-line background; do
  copy="$out/run-$mode"
  rm -rf "$copy"
  cp -a "$run_dir" "$copy"
  sets=()
  [ "$mode" = background ] && sets=(--set encoder.background_rounds=true)
  "$asi" train --run-dir "$copy" "${sets[@]}" > "$out/$mode.out" 2> "$out/$mode.err" &
  pid=$!
  sleep "$secs"
  kill -INT "$pid"
  wait "$pid" || true
  cp "$copy/metrics.jsonl" "$out/$mode.metrics.jsonl"
  rm -rf "$copy"
done
python3 - "$out" <<'PY'
import json, sys
out = sys.argv[1]
for mode in ["in-line", "background"]:
    recs = [json.loads(l) for l in open(f"{out}/{mode}.metrics.jsonl") if l.strip()]
    # the last launch's lines: wall_secs starts again at each launch
    cut = max([0] + [i for i in range(1, len(recs)) if recs[i].get("wall_secs", 0) < recs[i - 1].get("wall_secs", 0)])
    rows = [(r["wall_secs"], r["learner/ingest/env_steps"],
             r.get("learner/charts/updates_low", 0) + r.get("learner/charts/updates_high", 0),
             r.get("learner/phi/rounds", 0))
            for r in recs[cut:] if "learner/ingest/env_steps" in r and "wall_secs" in r]
    t0 = next(t for t, s, *_ in rows if s > rows[0][1])
    a, b = [r for r in rows if r[0] >= t0 + 60][0], rows[-1]
    dt = b[0] - a[0]
    print(f"{mode}: {dt:.0f} s, {(b[1] - a[1]) / dt:.1f} env steps/s, {(b[2] - a[2]) / dt:.1f} updates/s, φ rounds {a[3]:.0f} -> {b[3]:.0f}")
PY
