#!/usr/bin/env bash
# Side-by-side Ant speed: rapier (asi bench env) and the same Ant in MuJoCo, in one run,
# alternating ROUNDS times (default 5) so that machine load affects both alike. Prints each
# round's figures and ratio, then the medians. Each figure is already a median of 5 repeats.
set -euo pipefail
cd "$(dirname "$0")/.."
ROUNDS="${ROUNDS:-5}"
bash scripts/fidelity/setup.sh >/dev/null
cargo build --release --bin asi --quiet
ratios=()
rapier_all=()
mujoco_all=()
for i in $(seq 1 "$ROUNDS"); do
  r=$(./target/release/asi bench env --task antmaze-u --steps 2000 | awk '/^env_steps_per_sec/ {print $2}')
  m=$(.venv-fidelity/bin/python scripts/fidelity/mujoco_fidelity.py --speed-only | awk '{print $2}')
  ratio=$(python3 -c "print(round($r/$m, 2))")
  echo "round $i: rapier $r  mujoco $m  ratio $ratio  (load $(cut -d' ' -f1 /proc/loadavg))"
  ratios+=("$ratio"); rapier_all+=("$r"); mujoco_all+=("$m")
done
median() { python3 -c "import statistics, sys; print(statistics.median(float(v) for v in sys.argv[1:]))" "$@"; }
echo "median: rapier $(median "${rapier_all[@]}")  mujoco $(median "${mujoco_all[@]}")  ratio $(median "${ratios[@]}")"
