#!/usr/bin/env bash
# Re-measures docs/results.md "Current results" at the checked-out commit, on this machine.
# Usage: bash scripts/current_results.sh OUT [SHARED]   (SHARED: the shared data folder,
# default ../shared next to the repository; needs spgeo installed from this checkout).
# Two jobs side by side (the machine's two cores); each command's stdout / stderr go to
# OUT/NAME.out / .err, its exit code and seconds to OUT/status.txt, tables and JSON to OUT/NAME/.
set -u
OUT=$1; SHARED=${2:-"$(cd "$(dirname "$0")/.." && pwd)/../shared"}
mkdir -p "$OUT"; cd "$(dirname "$0")/.."
git rev-parse --short HEAD > "$OUT/commit.txt"; date -u > "$OUT/date.txt"
run() { local n=$1 s=$SECONDS; shift; "$@" > "$OUT/$n.out" 2> "$OUT/$n.err"; echo "$n rc=$? $((SECONDS - s)) s" >> "$OUT/status.txt"; }
FASTDEPTH="$SHARED/models/fastdepth/fastdepth_nyu_224.onnx"
( run completion spgeo eval completion_real --frontends classical --depth-model "$FASTDEPTH" --out "$OUT/completion"
  run frontier spgeo eval vo_frontier --datasets 7scenes --resolutions 320x240 --frontends classical depth --set-grid defaults --out "$OUT/frontier"
  run integration spgeo eval bench_integration --runs 15 --solvers cholesky direct ) &
( run long_run spgeo eval vo_long_run --out "$OUT/long_run" --sequences 7scenes,7scenes-palindrome,synthetic-loop,kitti --variants default,loops,no-landmarks --reference colmap
  run synthetic spgeo eval vo_synthetic --frames 150 --seeds 0 1 2 3 --out "$OUT/synthetic"
  run sfm_ablation spgeo eval sfm_ablation --out "$OUT/sfm_ablation"
  run demo spgeo demo --out "$OUT/demo" ) &
wait
cat "$OUT/status.txt"
