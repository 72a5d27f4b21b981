#!/usr/bin/env bash
# The benchmarks and GPU checks run on a lent GPU machine (no network there).
# The packages its image lacks (colour-science, OpenImageIO) travel as wheels
# in .whl/ (benchmarks/README.md, "On a GPU", says how). The records land in
# $OUT after each step, so a later step that fails or runs out of time keeps
# them; the exit status is that of the first step that failed.
set -euo pipefail
export PYTHONUNBUFFERED=1
label=${1:-gpu}
out=${OUT:-/tmp}
stamp=$(mktemp)
# only the records written by this run, not the committed ones of the same label
save() { find benchmarks/results -name "*_${label}*.json" -newer "$stamp" -exec cp {} "$out/" \; ; }
trap save EXIT
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:$PWD
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv
python3 -c "import jax; print(jax.__version__, jax.devices())"
# The whole render process (pfstmo is not on the machine: jaxadapt alone).
python3 benchmarks/bench_render.py --sizes 3840x2160:40 1920x1080:60 --repeats 2 \
    --label "$label"
save
for size in 1920x1080 3840x2160; do
    python3 benchmarks/bench_pattanaik2000.py --size $size --frames 60 --repeats 5 \
        --label "$label" --no-pfstmo
    save
done
python3 benchmarks/bench_jacobs2015.py --size 1920x1080 --frames 60 --repeats 5 --label "$label"
save
python3 benchmarks/bench_observer.py --label "$label"
save
# The live viewer at the 2015 paper's size (frames capped at 60 a second, as a display).
python3 benchmarks/bench_viewer.py --sizes 384x216 1920x1080 --label "$label"
save
# GPU correctness: the operator and kinetics tests on the GPU backend.
python3 -m pytest -o addopts="" -q -p no:cacheprovider -p no:warnings tests/test_pattanaik2000.py \
    tests/test_fused.py tests/test_jacobs2015.py tests/test_kinetics.py \
    tests/test_kinetics_jacobs.py 2>&1 | tail -3
