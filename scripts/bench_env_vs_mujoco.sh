#!/usr/bin/env bash
# Side-by-side Ant speed: rapier (asi bench env) and the same Ant in MuJoCo, in one run,
# alternating three times so that machine load affects both alike. Prints the ratio.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/fidelity/setup.sh >/dev/null
cargo build --release --bin asi 2>/dev/null
for i in 1 2 3; do
  r=$(./target/release/asi bench env --task antmaze-u --steps 2000 | awk '/^env_steps_per_sec/ {print $2}')
  m=$(.venv-fidelity/bin/python scripts/fidelity/mujoco_fidelity.py --speed-only | awk '{print $2}')
  echo "round $i: rapier $r  mujoco $m  ratio $(python3 -c "print(round($r/$m, 2))")"
done
