#!/usr/bin/env bash
# One-command GPU check: does training run on a CUDA GPU here, and how fast?
#
#   tools/gpu_check.sh [OUT_DIR]            (default OUT_DIR: gpu_check/; GPU_CHECK_STEPS=2000)
#
# 1. SAC updates/s on cuda (ours and SB3, benchmarks/run.py sac -- --device cuda) and, for scale, ours
#    on this machine's CPU (--device cpu, all cores);
# 2. a short dlo-train run (All, GPU_CHECK_STEPS steps) three ways: SAC on cpu + sim on cpu, SAC on
#    cuda + sim on cpu, SAC on cuda + sim on cuda (train.device / train.sim_arch); wall times from
#    their done.json; the cuda-trained policy is then evaluated on the CPU (checkpoints load on either);
# 3. the simulator on cuda (DLO_TI_ARCH=cuda benchmarks/run.py sim, batches 1 / 256 / 4096).
# Everything is logged under OUT_DIR; OUT_DIR/summary.json gathers the figures and is printed.
# Exit: 0 all steps passed, 1 a step failed (its log says why), 2 no CUDA GPU usable here (one
# line, nothing run). The setup installs torch's CPU build: on a GPU machine install the CUDA
# build of the same torch version into .venv first (the line below says so when it is missing).
set -uo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
OUT="${1:-$ROOT/gpu_check}"
STEPS="${GPU_CHECK_STEPS:-2000}"
if [ ! -f "$ROOT/scripts/env.sh" ]; then
  echo "gpu_check: no scripts/env.sh: run scripts/setup.sh first" >&2
  exit 2
fi
set +u; source "$ROOT/scripts/env.sh"; set -u
cd "$ROOT"

# preflight: torch and Taichi must both see a CUDA device (one line and exit 2 otherwise)
if ! reason="$(python - <<'EOF' 2>/dev/null
import sys
import torch
if not torch.cuda.is_available():
    build = "a CPU build: install torch's CUDA build of the same version" if torch.version.cuda is None \
        else f"built for CUDA {torch.version.cuda}"
    print(f"no CUDA GPU visible to torch {torch.__version__} ({build})")
    sys.exit(1)
from dlo_common import taichi_runtime
try:
    taichi_runtime.init("cuda")
except ValueError as error:
    print(f"torch sees {torch.cuda.get_device_name(0)}, but Taichi cannot use it ({error})")
    sys.exit(1)
print(torch.cuda.get_device_name(0))
EOF
)"; then
  echo "gpu_check: ${reason:-the CUDA check failed (python error)}; nothing run" >&2
  exit 2
fi
gpu="$reason"
mkdir -p "$OUT"
echo "[gpu_check] $gpu; logs and summary in $OUT"
failed=0
step() {  # step NAME COMMAND...: run, log to OUT/NAME.log, report time and status
  local name="$1"; shift
  local start=$SECONDS
  if "$@" > "$OUT/$name.log" 2>&1; then
    echo "[gpu_check] $name: ok ($((SECONDS - start)) s)"
  else
    echo "[gpu_check] $name: FAILED ($((SECONDS - start)) s), see $OUT/$name.log"
    failed=1
  fi
}
cores="$(nproc)"
step bench_sac_cuda python benchmarks/run.py sac -- --device cuda --threads "$cores" --rounds 3 --updates 300
step bench_sac_cpu python benchmarks/run.py sac -- --device cpu --threads "$cores" --rounds 3 --updates 50 --no-sb3
for variant in "cpu cpu" "cuda cpu" "cuda cuda"; do
  set -- $variant
  rm -rf "$OUT/train_sac-$1_sim-$2"
  step "train_sac-$1_sim-$2" dlo-train --modalities All --seed 0 --steps "$STEPS" --no-progress \
    --out "$OUT/train_sac-$1_sim-$2" train.device="$1" train.sim_arch="$2" train.num_threads="$cores" \
    train.eval_every=500 train.checkpoint_every=1000
done
step eval_cuda_policy_on_cpu dlo-evaluate --checkpoint "$OUT/train_sac-cuda_sim-cuda/policy.pt" --episodes 20 \
  --seed 5000 --json "$OUT/eval_cuda_policy_on_cpu.json"
step bench_sim_cuda env DLO_TI_ARCH=cuda python benchmarks/run.py sim -- --seconds 1 --repeats 2 --batches 1 256 4096

python - "$OUT" "$gpu" "$STEPS" > "$OUT/summary.json" <<'EOF'
import json, sys
from pathlib import Path
out, gpu, steps = Path(sys.argv[1]), sys.argv[2], int(sys.argv[3])

def last_json(name):  # benchmarks/run.py's line (last): the benchmark's JSON, or the record with its error
    try:
        record = json.loads((out / f"{name}.log").read_text().strip().splitlines()[-1])
    except (OSError, ValueError, IndexError):
        return None
    return record.get("result", record) if isinstance(record, dict) else None

def done(name):
    try:
        return json.loads((out / name / "done.json").read_text())
    except (OSError, ValueError):
        return None

def held(result):  # hold-the-end fractions under the paper's rule and the authors'
    return result and {"hold_the_end": result["hold_the_end"],
                       "hold_the_end_authors": result["authors_code"]["hold_the_end"]}

summary = {"gpu": gpu, "train_steps": steps}
for name in ("bench_sac_cuda", "bench_sac_cpu", "bench_sim_cuda"):
    summary[name] = last_json(name)
for name in ("train_sac-cpu_sim-cpu", "train_sac-cuda_sim-cpu", "train_sac-cuda_sim-cuda"):
    d = done(name)
    summary[name] = d and {"wall_time_s": d["wall_time_s"], "updates": d["updates"],
                           "updates_per_s_with_env_and_evaluations": round(d["updates"] / d["wall_time_s"], 1),
                           "best_eval": d.get("best_eval"), "held_out_test": held(d.get("test"))}
try:
    summary["eval_cuda_policy_on_cpu"] = held(json.loads((out / "eval_cuda_policy_on_cpu.json").read_text()))
except (OSError, ValueError, KeyError):
    summary["eval_cuda_policy_on_cpu"] = None
print(json.dumps(summary, indent=2))
EOF
cat "$OUT/summary.json"
exit "$failed"
