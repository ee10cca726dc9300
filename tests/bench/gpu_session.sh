#!/usr/bin/env bash
# The GPU checks of a session lent a device machine (issue 56), as one prepared command. Steps, in
# the order given by STEPS (default "build_gpu bench tests build_cpu"):
#   build_gpu  the sofa export built with cage pairs and training on CUDA (bench_build.py)
#   bench      bench_gpu.py on that family: a cage pair, a training and a transfer on the CPU and on
#              CUDA; a group's pairs one at a time on a CPU core, batched on the CPU, batched on CUDA
#   tests      the CUDA tests
#   build_cpu  the same build on the CPUs
# Each step writes its figures under OUT as it ends, so a run stopped at its limit keeps what it did.
#
#   bash tests/bench/gpu_session.sh DATA OUT [WORKERS]
#   STEPS="tests build_gpu" STAGES=sample,template,paint,pairs,train bash tests/bench/gpu_session.sh DATA OUT 16
#
# DATA: the sofa export's folder (its train/ and inference/ meshes); OUT: where the figures go;
# WORKERS: build worker processes (8); STAGES: the builds' stages (default all: the evaluation's
# time is reported apart). Wheels the machine lacks go in ./.whl (an ignored folder): they are
# installed into /tmp/site first. A CUDA image with torch, numpy, scipy, pyarrow, Pillow and
# scikit-image lacked (2026-11, Python 3.12): trimesh, pygltflib, dataclasses-json, marshmallow,
# typing-inspect, xatlas, libigl and embreex (`pip download --no-deps --only-binary=:all:
# --python-version 3.12 --platform manylinux_2_28_x86_64 ... -d .whl NAME==VERSION`, the versions
# of this checkout's environment).
set -u
DATA=${1:?the sofa export folder}
OUT=${2:?an output folder}
WORKERS=${3:-8}
STEPS=${STEPS:-build_gpu bench tests build_cpu}
STAGES=${STAGES:-}
mkdir -p "$OUT"
if [ -d .whl ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
  export PYTHONPATH="/tmp/site:$PWD"
else
  export PYTHONPATH="$PWD"
fi
export PYTHONUNBUFFERED=1 PYTHONDONTWRITEBYTECODE=1
{ nvidia-smi -L; nproc; python3 -c 'import torch, sys; print(sys.version.split()[0], torch.__version__, torch.cuda.get_device_name(0) if torch.cuda.is_available() else "no CUDA")'; } > "$OUT/machine.txt" 2>&1
build() {  # build DEVICE
  python3 tests/bench/bench_build.py --folder "$DATA" --runs process --workers "$WORKERS" ${STAGES:+--stages "$STAGES"} \
    --set "{\"cage\": {\"device\": \"$1\"}, \"train\": {\"device\": \"$1\"}}" --work "/tmp/build_$1_$WORKERS" --out "$OUT/build_$1_$WORKERS.json"
}
for s in $STEPS; do
  echo "== $(date +%T) $s (workers $WORKERS${STAGES:+, stages $STAGES})"
  case $s in
    build_gpu) build cuda ;;
    build_cpu) build cpu ;;
    bench) python3 tests/bench/bench_gpu.py --family "/tmp/build_cuda_$WORKERS/process0" --repeats 3 --pairs 16 --out "$OUT/gpu.json" ;;
    tests)
      python3 -m pytest -q -p no:cacheprovider tests/test_cage_device.py tests/test_device.py::test_cage_training_and_transfer_on_cuda_agree_with_the_cpu \
        tests/test_corrnet.py::test_cuda_train_predict_save_load > "$OUT/tests.txt" 2>&1
      tail -3 "$OUT/tests.txt" ;;
    *) echo "unknown step $s"; exit 2 ;;
  esac
done
echo "== $(date +%T) done"
