#!/usr/bin/env bash
# Run HERE (a machine with PyPI), in the checkout the device tool sends, before benchmarks/gpu.sh
# runs on the GPU machine (which reaches nothing outside itself):
#   .whl/      the Python packages its image lacks, as wheels for its Python 3.12 / x86-64
#              (gsplat, which compiles its CUDA kernels there; viser and what it needs beyond the
#              image's packages, for the viewer stage; trimesh)
#   .gpudata/  copies of the real sequences (the device tool sends the repository only, and
#              ../shared/data is outside it); both folders are ignored by git and are named in
#              the run's `carry`. Never commit them.
#
#   bash benchmarks/gpu_prepare.sh [DATA_DIR] [SEQUENCE ...]
# prints the sizes and the two device calls of docs/gpu.md (the data of all four sequences and
# the wheels exceed one call's 64 MiB, so 7-Scenes goes in the first call, SUN3D in the second).
set -eu
REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$REPO"
DATA="${1:-$REPO/../shared/data}"
shift || true
SEQS=("$@")
[ ${#SEQS[@]} -eq 0 ] && SEQS=(7scenes_redkitchen_300 sun3d_3dmatch_fragment1 sun3d_3dmatch_fragment2)
PY="${PYTHON:-python3}"
mkdir -p .whl .gpudata
"$PY" -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 \
    --platform manylinux2014_x86_64 --platform manylinux1_x86_64 --platform manylinux_2_5_x86_64 -d .whl \
    gsplat==1.5.3 viser==1.1.1 msgspec==0.23.0 trimesh==5.2.0 websockets==17.4 zstandard==0.25.0
for seq in "${SEQS[@]}"; do
  if [ -d "$DATA/$seq" ]; then
    rm -rf ".gpudata/$seq"; cp -r "$DATA/$seq" ".gpudata/$seq"
  else
    echo "gpu_prepare.sh: $DATA/$seq not found (skipped)" >&2
  fi
done
{ git check-ignore -q .whl && git check-ignore -q .gpudata; } || { echo "gpu_prepare.sh: .whl/.gpudata are not ignored by git" >&2; exit 1; }
du -sh .whl .gpudata/* 2>/dev/null
echo "tracked + untracked-not-ignored files: $(git ls-files -co --exclude-standard | xargs du -cb 2>/dev/null | tail -1)"
GSPLAT=$(ls .whl/gsplat-*.whl | head -1)
cat <<MSG
device call A (~8 min): carry [".whl", ".gpudata/7scenes_redkitchen_300"], timeout_s 600:
  bash benchmarks/gpu.sh --data .gpudata --sequences synthetic,7scenes_redkitchen_300 --out \$OUT
device call B (~3 min, right after A): carry ["$GSPLAT", ".gpudata/sun3d_3dmatch_fragment1", ".gpudata/sun3d_3dmatch_fragment2"], timeout_s 420:
  bash benchmarks/gpu.sh --data .gpudata --sequences sun3d_3dmatch_fragment1,sun3d_3dmatch_fragment2 --stages setup,slam --out \$OUT
MSG
