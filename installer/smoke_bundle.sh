#!/usr/bin/env bash
# Smoke test of a built Linux bundle (bash installer/build.sh smoke, or directly):
#
#   bash installer/smoke_bundle.sh [BUNDLE_DIR]      (default dist/talus)
#
# 1. `talus --version` answers;
# 2. a CUDA-free `talus demo --no-gui` (64 px, 2 frames, CUDA hidden) writes a complete study;
# 3. under Xvfb, `talus gui --smoke` opens the window on its welcome page and closes it
#    (first start of the bundle: the cold start), then once more (warm);
# 4. `talus gui --smoke --demo STUDY` opens that study and closes the window through its normal
#    close path (the study's journal and lock closed): exit 0, no traceback.
# Prints one line per step with its time, and the bundle's size. Exit status 0 when all passed.
# Every cache, setting and output goes to a temporary folder (removed at the end).
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
B="$(cd "${1:-$ROOT/dist/talus}" && pwd)"
T="$B/talus"
[ -x "$T" ] || { echo "smoke: no executable $T (build it with bash installer/build.sh bundle)" >&2; exit 1; }
command -v xvfb-run >/dev/null || { echo "smoke: xvfb-run not found (apt-get install xvfb xauth)" >&2; exit 1; }
TMP="$(mktemp -d "${TMPDIR:-/tmp}/talus-smoke.XXXXXX")"
trap 'rm -rf "$TMP"' EXIT
export XDG_CACHE_HOME="$TMP/cache" WARP_CACHE_PATH="$TMP/cache/warp" TALUS_SETTINGS_DIR="$TMP/settings"
export XDG_DATA_HOME="$TMP/data" TALUS_DEMO_DIR="$TMP/welcome-demo" QT_QPA_PLATFORM=xcb
XVFB=(xvfb-run -a -s "-screen 0 1280x1024x24")
now() { date +%s.%N; }
since() { python3 -c "import sys; print(f'{float(sys.argv[2]) - float(sys.argv[1]):.1f}')" "$1" "$(now)"; }
fail() { echo "smoke: FAILED: $*" >&2; exit 1; }

echo "bundle: $B ($(du -sh "$B" | cut -f1))"

t=$(now)
"$T" --version | grep -q '^talus ' || fail "talus --version"
echo "talus --version: $(since "$t") s"

t=$(now)
CUDA_VISIBLE_DEVICES="" "$T" demo --no-gui --device cpu --pixels 64 --frames 2 --out "$TMP/demo" \
    >"$TMP/demo.json" 2>"$TMP/demo.log" || { tail -20 "$TMP/demo.log" >&2; fail "talus demo --no-gui"; }
grep -q '"status": "complete"' "$TMP/demo.json" || fail "demo summary not complete: $(head -c 400 "$TMP/demo.json")"
[ -f "$TMP/demo/study.json" ] || fail "no study.json in the demo folder"
echo "talus demo --no-gui (CPU, 64 px, 2 frames): $(since "$t") s"

gui() {  # gui LABEL ARGS...: one `talus gui --smoke` run, its JSON line checked
    local label="$1"; shift
    local out="$TMP/gui-$label.log" t0
    t0=$(now)
    TALUS_SMOKE_T0="$t0" "${XVFB[@]}" "$T" gui --smoke "$@" >"$out" 2>&1 || { tail -30 "$out" >&2; fail "talus gui $label"; }
    grep -q '"smoke": "ok"' "$out" || { tail -30 "$out" >&2; fail "talus gui $label: no ok line"; }
    grep -i 'traceback' "$out" >&2 && fail "talus gui $label: traceback on stderr"
    echo "talus gui ($label): $(grep '"smoke"' "$out") total $(since "$t0") s"
}
gui "welcome, cold start"
gui "welcome, warm"
gui "demo study" --demo "$TMP/demo"
echo "smoke: all passed"
