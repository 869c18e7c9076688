#!/usr/bin/env bash
# Issue 6's side-by-side: Intel Embree 3 (the anchor benchmark in
# ../shared/anchors/embree) and isin's tracer benchmark (with the `bvh` and
# `obvhs` crates), back to back on the same meshes and ray sets, then one
# table of Mrays/s, build times, ratios, bytes per triangle and peak RSS.
#
#   scripts/bench-vs-embree.sh            # everything (about 10–15 minutes)
#   REPS=3 scripts/bench-vs-embree.sh     # fewer Embree repetitions
#   CASES="bunny sponza" scripts/bench-vs-embree.sh
#   ROUNDS=3 scripts/bench-vs-embree.sh   # measure both three times, alternating, and
#                                         # say in how many rounds each bar held
#   EMBREE_ISA=avx2 scripts/bench-vs-embree.sh  # Embree limited to its AVX2 kernels (the
#                                         # issue's reference machine has no AVX-512)
#
# Needs: root (or libembree-dev already installed) for apt-get, gcc, python3,
# cargo. Embree is built into target/embree/, never into ../shared. Raw outputs
# are kept in target/bench/ (embree-*.txt, tracer.json, tracer-1.6M.json).
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)
ANCHOR="$ROOT/../shared/anchors/embree"
MESHES="$ROOT/../shared/meshes"
OUT="$ROOT/target/bench"
mkdir -p "$OUT" "$ROOT/target/embree"

if ! dpkg -s libembree-dev >/dev/null 2>&1 && [ ! -e /usr/include/embree3/rtcore.h ]; then
  if [ "$(id -u)" = 0 ]; then
    echo "installing libembree-dev (apt-get)…"
    DEBIAN_FRONTEND=noninteractive apt-get install -y libembree-dev >/dev/null
  else
    echo "libembree-dev is not installed and this script is not running as root:" >&2
    echo "it cannot install it. Run: sudo apt-get install -y libembree-dev" >&2
    exit 1
  fi
fi
# The anchor's build.sh builds next to itself; build the same way into target/.
gcc -O2 -march=native -o "$ROOT/target/embree/embree_bench" "$ANCHOR/embree_bench.c" -lembree3 -lpthread -lm
# embree_bench takes no ISA option; with EMBREE_ISA the Python driver preloads a
# wrapper of rtcNewDevice that adds it, into embree_bench only.
EMBREE_PRELOAD=""
if [ -n "${EMBREE_ISA:-}" ]; then
  gcc -O2 -shared -fPIC -o "$ROOT/target/embree/embree_isa.so" "$ROOT/scripts/embree_isa.c" -ldl
  EMBREE_PRELOAD="$ROOT/target/embree/embree_isa.so"
fi

echo "== building isin's tracer benchmark (release)…"
cargo bench -p isin-tracer --bench tracer --no-run 2>&1 | tail -1

exec env EMBREE_PRELOAD="$EMBREE_PRELOAD" python3 "$ROOT/scripts/bench_vs_embree.py" --embree "$ROOT/target/embree/embree_bench" \
  --meshes "$MESHES" --out "$OUT" --reps "${REPS:-5}" --rounds "${ROUNDS:-1}" ${CASES:+--cases $CASES}
