#!/usr/bin/env bash
# One call on a lent GPU machine (the `device` tool of this workplace): the GPU≡CPU tests and
# the benchmarks on a real GPU, from binaries built on the development machine.
#
# Here, first:
#   cargo build --release --all-targets
#   bash benches/real_gpu.sh pack        # .devbin/bins.tgz: the stripped test/bench binaries
# then on the device, from the repository root, with .gl (the Vulkan loader, see the device
# tool's README) and .devbin carried:
#   bash benches/real_gpu.sh tests       # the machine, the GPU tests, hm1_exact on both
#                                        # backends, hybrid_step
#   bash benches/real_gpu.sh benches     # fem_step, lv at 1M tets, haptic lv_touch, hm1 stages
#   bash benches/real_gpu.sh ab          # the GPU tests, then the ratio tables and hm1's GPU
#                                        # stages of a change against .devbin/old.tgz (the
#                                        # hybrid_step, fem_step and profile_stages binaries of
#                                        # the build before it), in the same call
#   bash benches/real_gpu.sh fusion      # the GPU's fused passes off, measured, all in the same
#                                        # binary (PALPATE_GPU_FUSION=0/1/all): hybrid_step's GPU ratio tables
#                                        # and hm1's GPU stages, two rounds alternating
#   bash benches/real_gpu.sh round       # the GPU tests, design 8 under the tool (hm1_exact on
#                                        # both backends, its GPU stages and round trips to the
#                                        # CPU twin), fusion, and gpu_vs_cpu on 8 threads 8 times
#   bash benches/real_gpu.sh trip        # the GPU tests, design 8's round trips against
#                                        # .devbin/old.tgz's profile_stages, hm1 with nothing awake
#   bash benches/real_gpu.sh prerecord   # batches recorded ahead on and off (same binary):
#                                        # hybrid_step's GPU tables, hm1's and its core's steps
#   bash benches/real_gpu.sh next        # what the 2026-11-28 sessions built without a GPU, in
#                                        # one call: the GPU tests, one round of prerecord, the
#                                        # contact + sph_stress fusion (PALPATE_GPU_FUSION=all)
#                                        # against the default, hm1 and its core with nothing
#                                        # awake (t = 8), hm1_exact's round trips without the
#                                        # tangent forces
#   bash benches/real_gpu.sh hang        # the GPU tests, then gpu_vs_cpu on 8 threads with one
#                                        # device per binary and with one per test, 6 runs each
# (calls of about five minutes each; each writes $OUT/log.txt).
set -u
BINS="gpu_vs_cpu particles contact cardiac_gpu cardiac_wiring lv_mesh step_plan cli exact_coupling gpu_errors hybrid_step fem_step"

if [ "${1:-}" = "pack" ]; then
  set -e
  rm -rf .devbin/bin .devbin/bins.tgz && mkdir -p .devbin/bin
  for n in $BINS; do
    f=$(ls -t target/release/deps/"$n"-* | grep -v '\.d$' | head -1)
    cp "$f" .devbin/bin/"$n"
  done
  cp target/release/palpate target/release/examples/profile_stages .devbin/bin/
  strip .devbin/bin/*
  (cd .devbin && tar czf bins.tgz bin && rm -rf bin)
  ls -la .devbin
  exit 0
fi

OUT=${OUT:-/tmp/out}
mkdir -p "$OUT"
log=$OUT/log.txt
for f in .gl/*.deb; do dpkg -x "$f" /; done
ldconfig
tar xzf .devbin/bins.tgz -C .devbin
B=$PWD/.devbin/bin
# The test binaries were built in /work/main: their CARGO_BIN_EXE_palpate and manifest paths
# point there.
if [ ! -e /work/main ]; then mkdir -p /work && ln -s "$PWD" /work/main; fi
mkdir -p target/release && cp "$B/palpate" target/release/palpate
export XDG_RUNTIME_DIR=/tmp
section() { echo; echo "=== $* ($(date -u +%T))"; }

{
  section "machine"
  date -u
  nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.sm,clocks.mem,temperature.gpu --format=csv
  nproc
  "$B/palpate" info 2>&1 | head -40
} 2>&1 | tee "$log"
if ! "$B/palpate" info 2>&1 | grep -qi nvidia; then
  export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
  export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
  { section "info with VK_DRIVER_FILES"; "$B/palpate" info 2>&1 | head -40; } 2>&1 | tee -a "$log"
fi
if ! "$B/palpate" info 2>&1 | grep -qi nvidia; then echo "no NVIDIA adapter: stop" | tee -a "$log"; exit 3; fi
export PALPATE_ADAPTER=NVIDIA

GPU_TESTS="gpu_vs_cpu particles contact cardiac_gpu cardiac_wiring lv_mesh step_plan cli exact_coupling gpu_errors"

# Every GPU test binary once, on 8 test threads: the failing lines only, and each rc.
gpu_tests() {
  section "GPU tests (PALPATE_ADAPTER=NVIDIA)"
  for n in $GPU_TESTS; do
    echo "--- $n"
    timeout 100 "$B/$n" --test-threads 8 2>&1 | grep -A3 -E "^test |test result|panicked|assert|FAILED|error" | grep -v " ok$"
    echo "rc ${PIPESTATUS[0]}"
  done
}

# Design 8 under the tool: hm1_exact's 10 s on both backends, and the GPU's stages and round
# trips to its CPU twin at two holds.
design_8() {
  section "hm1_exact (design 8 under the tool; the GPU's activations on its CPU twin), 10 s: gpu, then cpu"
  for b in gpu cpu; do
    timeout 60 "$B/palpate" run hm1_exact --backend $b --out /tmp/hm1x_$b 2>&1 | tail -3
    grep -E '"(wall_seconds|steps_per_second|realtime_factor|max_displacement|active_particles_max)"' /tmp/hm1x_$b/summary.json
  done
  for t in 3.5 2.0; do
    section "hm1_exact GPU stages and round trips, tool held at t = $t"
    timeout 60 "$B/profile_stages" hm1_exact $t 200 gpu 2>&1 | tail -32
  done
}

# The GPU's fused passes on and off in the same binary: hybrid_step's GPU ratio tables and
# hm1's GPU stages, two rounds alternating.
fusion() {
  for round in 1 2; do
    for f in 0 1 all; do
      section "round $round, PALPATE_GPU_FUSION=$f: hybrid_step GPU ratio tables"
      PALPATE_GPU_FUSION=$f PALPATE_BENCH_BACKENDS=gpu timeout 120 "$B/hybrid_step" --bench no_criterion_group_matches 2>&1 | grep "|"
      section "round $round, PALPATE_GPU_FUSION=$f: hm1 GPU stages"
      PALPATE_GPU_FUSION=$f timeout 60 "$B/profile_stages" hm1 3.5 100 gpu 2>&1 | tail -22
    done
  done
}

# gpu_vs_cpu on 8 test threads, $1 runs of at most 20 s each (a pass takes 2-4 s), with
# PALPATE_TEST_DEVICE=$2 (shared: one device per test binary; per-test: one per test): the
# hang seen on the H200 (BENCHMARKS.md). A run still going after 20 s is hung: each of its
# threads' name, kernel wait channel and kernel stack are printed, then it is killed.
hang_check() {
  section "gpu_vs_cpu --test-threads 8 --nocapture, PALPATE_TEST_DEVICE=$2, $1 runs, 20 s each"
  for i in $(seq 1 "$1"); do
    PALPATE_TEST_DEVICE=$2 "$B/gpu_vs_cpu" --test-threads 8 --nocapture > /tmp/gvc_$i.txt 2>&1 &
    pid=$!
    for _ in $(seq 1 80); do sleep 0.25; kill -0 $pid 2>/dev/null || break; done
    if kill -0 $pid 2>/dev/null; then
      echo "run $i HUNG ($(grep -c ' ok$' /tmp/gvc_$i.txt) ok); its threads:"
      for t in /proc/$pid/task/*; do
        echo "  $(cat "$t/comm") | $(cat "$t/wchan") | $(head -4 "$t/stack" 2>/dev/null | awk '{print $2}' | tr '\n' ' ')"
      done
      kill -9 $pid; wait $pid 2>/dev/null
    else
      wait $pid
      echo "run $i rc $? ($(grep -c ' ok$' /tmp/gvc_$i.txt) ok; $(grep 'test result' /tmp/gvc_$i.txt))"
    fi
  done
}

if [ "${1:-}" = "ab" ]; then
  mkdir -p .devbin/old && tar xzf .devbin/old.tgz -C .devbin/old
  O=$PWD/.devbin/old
  {
    gpu_tests
    for round in 1 2; do
      for v in old new; do
        d=$B; [ $v = old ] && d=$O
        section "round $round, $v: hybrid_step ratio table"
        timeout 120 "$d/hybrid_step" --bench no_criterion_group_matches 2>&1 | grep "|"
        if [ $round = 1 ]; then
          section "round $round, $v: fem_step ratio table"
          timeout 120 "$d/fem_step" --bench no_criterion_group_matches 2>&1 | grep "|"
        fi
        section "round $round, $v: hm1 GPU stages"
        timeout 60 "$d/profile_stages" hm1 3.5 100 gpu 2>&1 | tail -17
      done
    done
    section "done"
  } 2>&1 | tee -a "$log"
  exit 0
fi

if [ "${1:-}" = "fusion" ]; then
  { fusion; section "done"; } 2>&1 | tee -a "$log"
  exit 0
fi

if [ "${1:-}" = "round" ]; then
  { gpu_tests; design_8; fusion; hang_check 8 shared; section "done"; } 2>&1 | tee -a "$log"
  exit 0
fi

# Design 8's GPU stages and round trips at t = 3.5 from .devbin/old.tgz's profile_stages
# (the build before a change) and this build's, alternating, two rounds; then what hm1 and
# its core alone cost with the tool gone (t = 8, nothing awake).
round_trip_ab() {
  mkdir -p .devbin/old && tar xzf .devbin/old.tgz -C .devbin/old
  for round in 1 2; do
    for v in old new; do
      d=$B; [ $v = old ] && d=$PWD/.devbin/old/bin
      section "round $round, $v: hm1_exact GPU stages and round trips, t = 3.5"
      timeout 60 "$d/profile_stages" hm1_exact 3.5 200 gpu 2>&1 | tail -30
    done
  done
  hm1_core
  for s in hm1 /tmp/hm1core.toml; do
    section "$s GPU stages, tool gone (t = 8)"
    timeout 60 "$B/profile_stages" $s 8 100 gpu 2>&1 | tail -17
  done
}

# hm1 without its particle layer (the same tets and tool): /tmp/hm1core.toml.
hm1_core() {
  awk '/^\[particles\]/{skip=1;next} /^\[/{skip=0} !skip' scenes/hm1.toml > /tmp/hm1core.toml
}

# Batches recorded ahead on and off in the same binary (PALPATE_GPU_PRERECORD): hybrid_step's
# GPU ratio tables and the whole steps of hm1 and its core alone, $1 rounds alternating.
prerecord() {
  hm1_core
  for round in $(seq "$1"); do
    for v in 0 1; do
      section "round $round, PALPATE_GPU_PRERECORD=$v: hybrid_step GPU ratio tables"
      PALPATE_GPU_PRERECORD=$v PALPATE_BENCH_BACKENDS=gpu timeout 120 "$B/hybrid_step" --bench no_criterion_group_matches 2>&1 | grep "|"
      for s in hm1 /tmp/hm1core.toml; do
        echo "$s: $(PALPATE_GPU_PRERECORD=$v timeout 60 "$B/profile_stages" $s 3.5 200 gpu 2>&1 | grep whole)"
      done
    done
  done
}

# The checks left for a GPU by the sessions of 2026-11-28 (no GPU lent to the second).
next_checks() {
  gpu_tests
  prerecord 1
  for f in 1 all 1 all; do
    section "PALPATE_GPU_FUSION=$f: hm1 whole steps and GPU stages, t = 3.5"
    PALPATE_GPU_FUSION=$f timeout 60 "$B/profile_stages" hm1 3.5 100 gpu 2>&1 | grep -E "whole|Contact|SphStress|total"
  done
  for s in hm1 /tmp/hm1core.toml; do
    section "$s GPU stages, tool gone (t = 8)"
    timeout 60 "$B/profile_stages" $s 8 100 gpu 2>&1 | tail -17
  done
  section "hm1_exact GPU stages and round trips, t = 3.5 (tangent forces no longer read back)"
  timeout 60 "$B/profile_stages" hm1_exact 3.5 200 gpu 2>&1 | tail -30
}

if [ "${1:-}" = "next" ]; then
  { next_checks; section "done"; } 2>&1 | tee -a "$log"
  exit 0
fi

if [ "${1:-}" = "prerecord" ]; then
  { prerecord 2; section "done"; } 2>&1 | tee -a "$log"
  exit 0
fi

if [ "${1:-}" = "trip" ]; then
  { gpu_tests; round_trip_ab; section "done"; } 2>&1 | tee -a "$log"
  exit 0
fi

if [ "${1:-}" = "hang" ]; then
  { gpu_tests; hang_check 6 shared; hang_check 6 per-test; section "done"; } 2>&1 | tee -a "$log"
  exit 0
fi

if [ "${1:-}" = "tests" ]; then
{
  gpu_tests
  design_8
  section "hybrid_step (criterion; ratio table last)"
  timeout 200 "$B/hybrid_step" --bench 2>&1 | grep -v "^$\|Warming\|Collecting\|Analyzing\|Found\|outlier\|mild\|severe\|change:\|Performance\|No change"
  section "done"
} 2>&1 | tee -a "$log"
exit 0
fi

{
  section "fem_step (criterion; ratio table and GPU stage times last)"
  timeout 200 "$B/fem_step" --bench 2>&1 | grep -v "^$\|Warming\|Collecting\|Analyzing\|Found\|outlier\|mild\|severe\|change:\|Performance\|No change"

  section "lv at 1,022,208 tets (resolution 22), 100 steps: gpu, then cpu (all cores)"
  sed 's/^resolution = 3 .*/resolution = 22/' scenes/lv.toml > /tmp/lv_1m.toml
  for b in gpu cpu; do
    timeout 120 "$B/palpate" run /tmp/lv_1m.toml --steps 100 --backend $b --out /tmp/lv1m_$b 2>&1 | tail -3
    grep -E '"(backend|steps|wall_seconds|steps_per_second|realtime_factor|max_displacement)"' /tmp/lv1m_$b/summary.json
  done

  section "haptic lv_touch, 3 mm scripted press, 3 s, gpu then cpu"
  printf 't,x,y,z\n0,0,0,0\n0.5,-0.003,0,0\n3,-0.003,0,0\n' > /tmp/press.csv
  for b in gpu cpu; do
    timeout 30 "$B/palpate" haptic --device scripted:/tmp/press.csv --seconds 3 --backend $b --out /tmp/hap_$b 2>&1 | tail -4
  done

  section "hm1 stage times on the GPU (timestamp queries), tool held at t = 3.5"
  timeout 60 "$B/profile_stages" hm1 3.5 100 gpu 2>&1 | tail -41
  section "done"
} 2>&1 | tee -a "$log"
