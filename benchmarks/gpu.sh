#!/usr/bin/env bash
# Every CUDA figure of docs/gpu.md in one run on a GPU machine; JSON under $OUT (default ./gpu_out).
#
#   bash benchmarks/gpu.sh [--data DIR] [--sequences a,b] [--stages setup,pytest,slam,render,viewer]
#                          [--out DIR] [--budget SECONDS] [--dry-run-cpu]
#
# Stages (each under its own `timeout`, cut to what is left of --budget, default 540 s, so the
# summary is written inside a 600 s device call; a stage that fails or times out is recorded and
# the next one runs):
#   setup   installs the wheels carried in .whl/ (pip --no-index --target /tmp/site), then imports
#           gsplat and renders once so its CUDA kernels compile (TORCH_CUDA_ARCH_LIST=9.0)
#   pytest  pytest -m cuda on the test files that have CUDA tests        -> pytest_cuda.json
#   slam    benchmarks/slam.py: the `splatam` preset sequential (the paper's; started in the
#           background right after setup, while pytest runs: its accuracy is the reference, its
#           speed is marked concurrent) and then the `gpu` preset live, one run at a time, alone
#           on the GPU, on each sequence                                  -> slam.json
#   viewer  benchmarks/viewer_gpu.py: the `gpu` preset live headless and in the viewer with a
#           headless websocket client                                     -> viewer.json
#   render  benchmarks/render.py --backends cuda                          -> render.json
# and summary.json (machine, per-stage seconds and exit codes, the targets checked, peak GPU
# memory) and log.txt. --data: the folder holding the real sequences (../shared/data does not
# travel to the device: benchmarks/gpu_prepare.sh copies them into .gpudata/, which git ignores,
# to be carried). Sequences missing there are skipped and say so. --dry-run-cpu: every stage on
# the CPU on tiny inputs (3 frames, 80x60, a few iterations) to check the script itself.
set -u
REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$REPO"
PY="${PYTHON:-python3}"
DATA=".gpudata"
SEQUENCES="synthetic,7scenes_redkitchen_300,sun3d_3dmatch_fragment1,sun3d_3dmatch_fragment2"
STAGES="setup,pytest,slam,render,viewer"
OUTDIR="${OUT:-$REPO/gpu_out}"
DRY=0
BUDGET_SET=0
BUDGET=540          # seconds for the whole script: each stage's limit is cut to what is left
while [ $# -gt 0 ]; do
  case "$1" in
    --data) DATA="$2"; shift 2 ;;
    --sequences) SEQUENCES="$2"; shift 2 ;;
    --stages) STAGES="$2"; shift 2 ;;
    --out) OUTDIR="$2"; shift 2 ;;
    --dry-run-cpu) DRY=1; shift ;;
    --budget) BUDGET="$2"; BUDGET_SET=1; shift 2 ;;
    *) echo "gpu.sh: unknown argument $1" >&2; exit 2 ;;
  esac
done
DEADLINE=$(( $(date +%s) + BUDGET ))
mkdir -p "$OUTDIR"
OUTDIR="$(cd "$OUTDIR" && pwd)"
WORK="${GPU_WORK:-/tmp/splatam_gpu_work}"
rm -rf "$WORK"; mkdir -p "$WORK"
LOG="$OUTDIR/log.txt"
: > "$LOG"
STAGEFILE="$WORK/stages.jsonl"
: > "$STAGEFILE"
export PYTHONUNBUFFERED=1 OMP_WAIT_POLICY=PASSIVE
export TORCH_CUDA_ARCH_LIST="${TORCH_CUDA_ARCH_LIST:-9.0}" MAX_JOBS="${MAX_JOBS:-16}"
export PYTHONPATH="$REPO:/tmp/site${PYTHONPATH:+:$PYTHONPATH}"

has() { case ",$STAGES," in *",$1,"*) return 0 ;; *) return 1 ;; esac; }
log() { echo "[gpu.sh $(date -u +%H:%M:%S)] $*" | tee -a "$LOG" >&2; }
# run NAME LIMIT_S STDOUT CMD...: the command under `timeout`, its stdout to the file STDOUT ("-":
# log.txt), its stderr to log.txt, its seconds and exit code to the stage list (124: timed out)
run() {
  local name="$1" limit="$2" dest="$3"; shift 3
  [ "$dest" = "-" ] && dest="$LOG"
  local left=$(( DEADLINE - $(date +%s) - 20 ))      # 20 s kept for the summary
  if [ "$left" -lt 10 ]; then
    log "stage $name skipped: the budget (--budget) is spent"
    echo "{\"stage\": \"$name\", \"rc\": null, \"skipped\": \"budget spent\", \"limit_s\": $limit}" >> "$STAGEFILE"
    return 1
  fi
  [ "$left" -lt "$limit" ] && limit=$left
  local t0=$(date +%s%N)
  log "stage $name (limit ${limit}s): $*"
  timeout --kill-after=15 "$limit" "$@" >>"$dest" 2>>"$LOG"
  local rc=$?
  local ms=$(( ($(date +%s%N) - t0) / 1000000 ))
  echo "{\"stage\": \"$name\", \"rc\": $rc, \"seconds\": $ms.0e-3, \"limit_s\": $limit}" >> "$STAGEFILE"
  log "stage $name: exit $rc after ${ms} ms"
  return $rc
}

if [ "$DRY" = 1 ]; then
  DEVICE=cpu
  MAXF="--max-frames 3"
  cat > "$WORK/dry_gpu.yaml" <<'EOF'
# gpu.sh --dry-run-cpu: the gpu preset, tiny, with the torch alignment forced on the CPU
base: gpu
resolution: [80, 60]
checkpoint_every: 0
tracking: {iterations: 1, align: {iterations: 2, backend: torch}}
mapping: {iterations: 2, first_frame_iterations: 4}
EOF
  cat > "$WORK/dry_splatam.yaml" <<'EOF'
base: splatam
resolution: [80, 60]
checkpoint_every: 0
tracking: {iterations: 2}
mapping: {iterations: 2, first_frame_iterations: 4}
EOF
  GPU_PRESET="$WORK/dry_gpu.yaml"; REF_PRESET="$WORK/dry_splatam.yaml"
  [ "$BUDGET_SET" = 1 ] || DEADLINE=$(( $(date +%s) + 3600 ))   # the dry run's 2-core timings are no guide to the device's
  L_SETUP=120; L_PYTEST=300; L_REF=600; L_GPU=600; L_RENDER=300; L_VIEWER=300
  RENDER_ARGS="--backends cpu --sizes 160x120 --gaussians 2000 --repeats 2"
  VIEWER_ARGS="--frames 4 --size 80x60 --config $GPU_PRESET --device cpu"
else
  DEVICE=cuda
  MAXF=""
  GPU_PRESET="gpu"; REF_PRESET="splatam"
  # Sized for one call of ~8 minutes (docs/gpu.md); each limit ends its stage, not the script.
  L_SETUP=${L_SETUP:-200}; L_PYTEST=${L_PYTEST:-240}; L_REF=${L_REF:-300}; L_GPU=${L_GPU:-180}
  L_RENDER=${L_RENDER:-60}; L_VIEWER=${L_VIEWER:-120}
  RENDER_ARGS="--backends cuda --sizes 320x240,640x480 --gaussians 50000,200000,1000000 --repeats 21"
  VIEWER_ARGS="--frames 40 --size 640x480 --config gpu --device cuda"
fi
log "repo $REPO, data $DATA, sequences $SEQUENCES, stages $STAGES, device $DEVICE, out $OUTDIR"

# ------------------------------------------------------------------ setup
if has setup; then
  if [ "$DRY" = 1 ]; then
    log "dry run: the wheels in .whl/ are for the device's Python 3.12; not installed here"
  elif ls .whl/*.whl >/dev/null 2>&1; then
    run wheels 120 - "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
        --target /tmp/site .whl/*.whl
  else
    log "no .whl/ here: using the packages installed (and /tmp/site if an earlier call left it)"
  fi
  run gsplat_build "$L_SETUP" "$WORK/setup.out" "$PY" - "$DEVICE" <<'EOF'
import json, sys, time
import numpy as np, torch
t0 = time.perf_counter()
info = dict(torch=torch.__version__, cuda_available=torch.cuda.is_available())
if sys.argv[1] == "cuda":
    from splat_core.render import cuda, render
    from splat_core.camera import Intrinsics
    from splat_core.gaussians import Gaussians
    ok = cuda.available()
    info.update(gsplat_available=ok, reason=cuda.unavailable_reason(), device=torch.cuda.get_device_name(0))
    if ok:
        import gsplat
        info["gsplat"] = gsplat.__version__
        n, dev = 1000, "cuda"
        g = Gaussians(torch.rand(n, 3, device=dev) + torch.tensor([0, 0, 2.0], device=dev), torch.rand(n, 3, device=dev),
                      torch.tensor([[1.0, 0, 0, 0]], device=dev).repeat(n, 1), torch.zeros(n, device=dev),
                      torch.full((n, 1), -4.0, device=dev))
        out = render(g, Intrinsics(60.0, 60.0, 31.5, 23.5, 64, 48), np.eye(4))
        torch.cuda.synchronize()
        info["first_render_ok"] = bool(torch.isfinite(out.color).all())
info["seconds"] = round(time.perf_counter() - t0, 1)
print("SETUP " + json.dumps(info))
sys.exit(0 if sys.argv[1] != "cuda" or info.get("first_render_ok") else 1)
EOF
  grep '^SETUP ' "$WORK/setup.out" | tail -1 | sed 's/^SETUP //' > "$WORK/setup.json"
fi

# ------------------------------------------------------------------ the splatam reference runs (background)
IFS=',' read -r -a SEQS <<< "$SEQUENCES"
REF_PIDS=()
start_reference_runs() {
  for seq in "${SEQS[@]}"; do
    run "slam_ref_$seq" "$L_REF" "$WORK/ref_$seq.jsonl" "$PY" benchmarks/slam.py --sequences "$seq" \
        --presets "$REF_PRESET@sequential" --data "$DATA" --device "$DEVICE" --work "$WORK/slam" $MAXF &
    REF_PIDS+=($!)
  done
}
if has slam; then
  start_reference_runs
  log "splatam reference runs started in the background: ${REF_PIDS[*]}"
fi

# ------------------------------------------------------------------ pytest -m cuda
if has pytest; then
  FILES=$(grep -rl --include="test_*.py" "mark.cuda" tests | tr '\n' ' ')
  run pytest_cuda "$L_PYTEST" - "$PY" -m pytest -m cuda -q -p no:cacheprovider --junitxml="$WORK/junit.xml" $FILES
  "$PY" - "$WORK/junit.xml" "$OUTDIR/pytest_cuda.json" "$FILES" <<'EOF'
import json, sys, xml.etree.ElementTree as ET
out = dict(files=sys.argv[3].split())
try:
    root = ET.parse(sys.argv[1]).getroot()
    suite = root if root.tag == "testsuite" else root.find("testsuite")
    out.update({k: int(suite.get(k, 0)) for k in ("tests", "failures", "errors", "skipped")})
    out["seconds"] = float(suite.get("time", 0))
    out["cases"] = []
    for case in suite.iter("testcase"):
        status = "passed"
        for kind in ("failure", "error", "skipped"):
            node = case.find(kind)
            if node is not None:
                status = kind
                out["cases"].append(dict(name=f"{case.get('classname')}::{case.get('name')}", status=status,
                                         message=(node.get("message") or "")[:500]))
                break
        else:
            out["cases"].append(dict(name=f"{case.get('classname')}::{case.get('name')}", status=status))
    out["passed"] = out["tests"] - out["failures"] - out["errors"] - out["skipped"]
except Exception as e:      # pytest did not get to write its report (timed out, crashed)
    out["error"] = f"no junit report: {type(e).__name__}: {e}"
json.dump(out, open(sys.argv[2], "w"), indent=1)
EOF
fi

# ------------------------------------------------------------------ the timed runs, alone on the GPU
if has slam; then
  for pid in "${REF_PIDS[@]}"; do wait "$pid"; done
  log "splatam reference runs done"
  run slam_gpu "$L_GPU" "$WORK/gpu_runs.jsonl" "$PY" benchmarks/slam.py --sequences "$SEQUENCES" \
      --presets "$GPU_PRESET@live" --data "$DATA" --device "$DEVICE" --work "$WORK/slam" $MAXF
fi
if has viewer; then
  run viewer "$L_VIEWER" "$OUTDIR/viewer.json" "$PY" benchmarks/viewer_gpu.py $VIEWER_ARGS
fi
if has render; then
  run render "$L_RENDER" "$OUTDIR/render.json" "$PY" benchmarks/render.py --json $RENDER_ARGS
fi

# ------------------------------------------------------------------ summary
nvidia-smi --query-gpu=name,memory.total,memory.used,driver_version --format=csv,noheader > "$WORK/smi.txt" 2>/dev/null || true
"$PY" benchmarks/gpu_summary.py --work "$WORK" --out "$OUTDIR" --gpu-preset "$GPU_PRESET" --ref-preset "$REF_PRESET" \
    --sequences "$SEQUENCES" --dry-run "$DRY" >>"$LOG" 2>&1 || log "summary failed (see log.txt)"
# log.txt comes back only under 16 MB: keep its end
tail -c 4000000 "$LOG" > "$WORK/log.tail" && mv "$WORK/log.tail" "$LOG"
log "done: $(ls "$OUTDIR" | tr '\n' ' ')"
cat "$OUTDIR/summary.json" 2>/dev/null | head -c 6000
