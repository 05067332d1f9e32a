#!/usr/bin/env bash
# How long `asi plot` (and the launcher's per-minute redraw of plots/curves.png, which reads
# the same way) takes on the metrics.jsonl of a long process-mode run: writes a synthetic
# run folder of LINES lines (default 121,000: a week at the default run.metrics_interval_secs
# of 5 s) of about 5 KB each (130 numeric keys, like a real AntMaze run's lines), then times
# ROUNDS plots (default 3) and prints wall seconds and peak memory of each and the median.
# Compare builds by setting ASI to another binary.
set -euo pipefail
command -v /usr/bin/time >/dev/null || { echo "needs /usr/bin/time (Debian package: time)" >&2; exit 1; }
cd "$(dirname "$0")/.."
LINES="${LINES:-121000}"
ROUNDS="${ROUNDS:-3}"
if [[ -z "${ASI:-}" ]]; then
  cargo build --release --bin asi --quiet
  ASI=./target/release/asi
fi
dir="$(mktemp -d)/week_s0"
mkdir -p "$dir"
trap 'rm -rf "$(dirname "$dir")"' EXIT
python3 - "$dir/metrics.jsonl" "$LINES" <<'PY'
import json, random, sys
path, lines = sys.argv[1], int(sys.argv[2])
rng = random.Random(0)
groups = ["learner/charts", "learner/ingest", "learner/sac_low", "learner/sac_high", "learner/phi",
          "learner/si", "graph-service/graph", "actor0/actor", "actor1/actor", "launcher"]
keys = [f"{g}/metric_{i:02d}" for g in groups for i in range(13)]
with open(path, "w") as f:
    for n in range(lines):
        line = {k: rng.random() * 1000 for k in keys}
        line["wall_secs"] = n * 5.0
        line["learner/ingest/env_steps"] = n * 400
        line["learner/charts/coverage"] = min(1.0, n / lines)
        if n % 50 == 0:
            line["evaluator0/eval/success_rate"] = rng.choice([0.0, 0.1, 0.5])
        f.write(json.dumps(line, separators=(",", ":")) + "\n")
PY
echo "$(wc -l < "$dir/metrics.jsonl") lines, $(du -m "$dir/metrics.jsonl" | cut -f1) MiB"
times=()
for i in $(seq 1 "$ROUNDS"); do
  out=$( { /usr/bin/time -f "%e %M" "$ASI" plot "$dir" --out "$dir/../curves.png" >/dev/null; } 2>&1 | tail -n 1)
  read -r secs kib <<<"$out"
  echo "round $i: ${secs} s, peak ${kib} KiB"
  times+=("$secs")
done
python3 -c "import statistics, sys; print('median', statistics.median(float(v) for v in sys.argv[1:]), 's')" "${times[@]}"
