#!/usr/bin/env bash
# Outputs a restructure must leave byte-identical (docs/history.md, "Restructure without
# behaviour change"), written by one spgeo executable into OUT:
#   vo7 / vo7-inline        spgeo vo on the shared 7-Scenes clip 0:300 (live, then inline mapping)
#   pal / pal-inline        the same on its palindrome 0..299..0 (599 frames, symlinks)
#   demo                    spgeo demo
#   sfm                     spgeo sfm on the 1st, 4th and 7th bundled TUM fr1_desk frames
#   complete.png            spgeo complete on the first TUM frame, 500 sensor-depth points
# Usage: bash scripts/compare_outputs.sh SPGEO OUT [SHARED]
#   SPGEO: the spgeo executable (e.g. a venv's bin/spgeo at the commit to compare)
#   SHARED: the shared/ folder (default ../shared beside the checkout)
# Compare two such folders with: bash scripts/compare_outputs.sh --diff OUT_A OUT_B
set -euo pipefail
cd "$(dirname "$0")/.."

if [ "${1:-}" = "--diff" ]; then
  a=$2; b=$3; rc=0
  # everything but the run reports and manifests (timings, time stamps)
  diff -rq -x report.json -x .spgeo-output.json -x '*.md' -x '*.log' "$a" "$b" || rc=1
  for t in "$a"/demo/*.md; do
    [ -e "$t" ] || continue
    echo "== table $(basename "$t") (lines differing, times included):"
    diff "$t" "$b/demo/$(basename "$t")" | grep -c '^<' || true
  done
  exit $rc
fi

SPGEO=$1; OUT=$2; SHARED=${3:-../shared}
DATA="$SHARED/data"
mkdir -p "$OUT"
OUT=$(cd "$OUT" && pwd); DATA=$(cd "$DATA" && pwd)
SEVEN="$DATA/7scenes_redkitchen_dev"; TUM="$DATA/tum_fr1_desk_9"

PAL="$OUT/palindrome-input"
if [ ! -d "$PAL" ]; then
  mkdir -p "$PAL"; ln -s "$SEVEN/camera-intrinsics.txt" "$PAL/"
  n=0
  for i in $(seq 0 299) $(seq 298 -1 0); do
    src=$(printf 'frame-%06d' "$i"); dst=$(printf 'frame-%06d' "$n")
    for ext in color.jpg depth.png pose.txt; do ln -s "$SEVEN/$src.$ext" "$PAL/$dst.$ext"; done
    n=$((n + 1))
  done
fi
SPARSE="$OUT/sparse500.png"
[ -e "$SPARSE" ] || python3 - "$TUM" "$SPARSE" <<'EOF'
import sys, cv2, numpy as np
tum, out = sys.argv[1], sys.argv[2]
name = open(f"{tum}/depth.txt").read().split("\n")
name = [l.split()[1] for l in name if l and not l.startswith("#")][0]
d = cv2.imread(f"{tum}/{name}", cv2.IMREAD_UNCHANGED).astype(np.float64) / 5000.0
ys, xs = np.nonzero(d > 0)
pick = np.random.default_rng(0).choice(len(ys), 500, replace=False)
sparse = np.zeros(d.shape, np.uint16)
sparse[ys[pick], xs[pick]] = np.round(d[ys[pick], xs[pick]] * 1000).astype(np.uint16)
cv2.imwrite(out, sparse)
EOF

"$SPGEO" vo --dataset 7scenes "$SEVEN" --frames 0:300 --out "$OUT/vo7" --no-progress
"$SPGEO" vo --dataset 7scenes "$SEVEN" --frames 0:300 --out "$OUT/vo7-inline" --no-progress \
  --set mapping.mode=inline
"$SPGEO" vo --dataset 7scenes "$PAL" --out "$OUT/pal" --no-progress
"$SPGEO" vo --dataset 7scenes "$PAL" --out "$OUT/pal-inline" --no-progress --set mapping.mode=inline
"$SPGEO" demo --out "$OUT/demo"
rgb=($(ls "$TUM"/rgb/*.png))
"$SPGEO" sfm --ref "${rgb[0]}" --views "${rgb[3]}" "${rgb[6]}" \
  --intrinsics 517.3,516.5,318.6,255.3 --out "$OUT/sfm"
"$SPGEO" complete --rgb "${rgb[0]}" --sparse "$SPARSE" --intrinsics 517.3,516.5,318.6,255.3 \
  --out "$OUT/complete.png"
echo "compare_outputs: wrote $OUT"
