#!/usr/bin/env bash
# Set up a development environment for Talus and run it.
#
#   bash installer/dev.sh demo [talus demo options]   venv + GUI extra, then `talus demo --out demo_out`
#   bash installer/dev.sh test [pytest options]       system packages, venv + test extra, ruff,
#                                                     import contracts, pytest under Xvfb (no
#                                                     options: two worker processes, see cmd_test)
#   bash installer/dev.sh gui  [talus gui options]    venv + GUI extra, then open the window
#   bash installer/dev.sh bundle                      venv + GUI extra, then the standalone folder
#                                                     dist/talus (installer/build.sh bundle)
#   bash installer/dev.sh lock                        rewrite installer/constraints.txt: the
#                                                     newest versions the ranges in pyproject.toml
#                                                     allow, installed into a fresh temporary venv
#
# Idempotent: re-running reuses the virtual environment (.venv, or $TALUS_VENV) and installs only
# what is missing. Needs Python >= 3.11 (python3.11 or python3; override with $TALUS_PYTHON).
# Every install is pinned by installer/constraints.txt (the exact versions CI tested); set
# TALUS_CONSTRAINTS to another file, or to an empty value to install from the ranges alone.
# System packages are installed with apt-get when running as root on Debian/Ubuntu; otherwise the
# missing ones are listed. The exit status is that of the command run (ruff, lint-imports or
# pytest for `test`).
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${TALUS_VENV:-$ROOT/.venv}"
LOCK="$ROOT/installer/constraints.txt"
CONSTRAINTS="${TALUS_CONSTRAINTS-$LOCK}"
XVFB_SCREEN="-screen 0 1280x1024x24"

# Runtime libraries of Qt's xcb platform plugin and VTK's OpenGL window, plus a font.
GUI_PACKAGES=(
    libgl1 libegl1 libgl1-mesa-dri libxkbcommon-x11-0 libxcb-cursor0 libxcb-icccm4
    libxcb-image0 libxcb-keysyms1 libxcb-render-util0 libxcb-shape0 libxcb-xinerama0
    libxcb-randr0 libxcb-xfixes0 libdbus-1-3 libfontconfig1 fonts-dejavu-core
)
# A virtual X server for the GUI tests.
TEST_PACKAGES=(xvfb xauth)

log() { printf '[dev.sh] %s\n' "$*" >&2; }
die() { log "error: $*"; exit 1; }

usage() {
    sed -n '2,/^set -euo/{/^#/p}' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2
}

# ---------------------------------------------------------------------------- system packages

apt_install() {  # apt_install PKG...: install the Debian packages that are not installed yet
    local missing=() pkg
    command -v dpkg >/dev/null 2>&1 || { log "not a Debian system: skipping system packages ($*)"; return 0; }
    for pkg in "$@"; do
        dpkg -s "$pkg" >/dev/null 2>&1 || missing+=("$pkg")
    done
    [ "${#missing[@]}" -eq 0 ] && return 0
    if [ "$(id -u)" -ne 0 ]; then
        log "warning: missing system packages: ${missing[*]}"
        log "         install them with: sudo apt-get install ${missing[*]}"
        return 0
    fi
    log "installing system packages: ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    if ! apt-get install -y -q --no-install-recommends "${missing[@]}" >&2; then
        log "package lists missing or stale: apt-get update"
        apt-get update -q >&2
        apt-get install -y -q --no-install-recommends "${missing[@]}" >&2
    fi
}

# ------------------------------------------------------------------------------------- python

python_ok() {  # python_ok EXE: is EXE a Python >= 3.11?
    "$1" -c 'import sys; sys.exit(sys.version_info < (3, 11))' >/dev/null 2>&1
}

find_python() {
    local candidate
    for candidate in "${TALUS_PYTHON:-}" python3.11 python3; do
        [ -n "$candidate" ] || continue
        if command -v "$candidate" >/dev/null 2>&1 && python_ok "$candidate"; then
            command -v "$candidate"
            return 0
        fi
    done
    die "Python >= 3.11 not found (tried \$TALUS_PYTHON, python3.11, python3); on Debian: apt-get install python3.11 python3.11-venv"
}

make_venv() {  # make_venv DIR: a new virtual environment in DIR
    local py
    py="$(find_python)"
    log "creating virtual environment $1 with $py"
    if ! "$py" -c 'import ensurepip, venv' >/dev/null 2>&1; then
        # Debian splits venv/ensurepip out of the interpreter package
        local ver
        ver="$("$py" -c 'import sys; print(f"{sys.version_info[0]}.{sys.version_info[1]}")')"
        apt_install "python${ver}-venv"
    fi
    "$py" -m venv --clear "$1" || die "could not create $1 (on Debian: apt-get install python3-venv)"
}

ensure_venv() {
    if [ -x "$VENV/bin/python" ] && python_ok "$VENV/bin/python" \
        && "$VENV/bin/python" -m pip --version >/dev/null 2>&1; then
        return 0
    fi
    make_venv "$VENV"
}

pip_install() {  # pip_install EXTRA: editable install of the project with that extra
    local pin=()
    if [ -n "$CONSTRAINTS" ]; then
        [ -f "$CONSTRAINTS" ] || die "constraints file $CONSTRAINTS not found (TALUS_CONSTRAINTS: expected a pip constraints file, or empty to install from the ranges in pyproject.toml)"
        pin=(-c "$CONSTRAINTS")
        log "installing talus-biplane[$1] into $VENV, pinned by ${CONSTRAINTS#"$ROOT/"}"
    else
        log "installing talus-biplane[$1] into $VENV from the ranges in pyproject.toml (unpinned)"
    fi
    # always re-run: cheap when satisfied, and it refreshes the editable finder when packages
    # are added to core/ or app/; a package at another version than the pin is replaced
    "$VENV/bin/python" -m pip install -q "${pin[@]}" -e "$ROOT[$1]" >&2
}

# ----------------------------------------------------------------------------------- commands

cmd_demo() {
    ensure_venv
    pip_install gui
    cd "$ROOT"
    log "running: talus demo --out demo_out $*"
    "$VENV/bin/talus" demo --out demo_out "$@"
}

cmd_gui() {
    apt_install "${GUI_PACKAGES[@]}"
    ensure_venv
    pip_install gui
    cd "$ROOT"
    if [ -z "${DISPLAY:-}" ] && [ -z "${WAYLAND_DISPLAY:-}" ]; then
        die "no display (DISPLAY is not set): run this from a desktop session or with ssh -X"
    fi
    QT_QPA_PLATFORM="${QT_QPA_PLATFORM:-xcb}" exec "$VENV/bin/talus" gui "$@"
}

cmd_test() {
    apt_install "${GUI_PACKAGES[@]}" "${TEST_PACKAGES[@]}"
    ensure_venv
    pip_install test
    cd "$ROOT"

    local cache status=0
    cache="$(mktemp -d "${TMPDIR:-/tmp}/talus-test-cache.XXXXXX")"
    # shellcheck disable=SC2064  # expand now: the path is fixed
    trap "rm -rf '$cache'" EXIT
    export XDG_CACHE_HOME="$cache/xdg" WARP_CACHE_PATH="$cache/warp" TALUS_TEST_CACHE_DIR="$cache"
    # Warp's compiled kernels are kept between runs beside the virtual environment that built
    # them (a new venv starts an empty cache; a cache grown past 1 GiB by old kernels is emptied):
    # the first run compiles them (tests/conftest.py points WARP_CACHE_PATH there)
    local kernels="${TALUS_TEST_KERNEL_CACHE:-$VENV/talus-test-kernels}"
    if [ -d "$kernels" ] && [ "$(du -sm "$kernels" | cut -f1)" -gt 1024 ]; then
        log "emptying the kernel cache $kernels (over 1 GiB)"
        rm -rf "$kernels"
    fi
    export TALUS_TEST_KERNEL_CACHE="$kernels"
    # Python's compiled modules, pytest's assert-rewritten test modules among them, go to a folder
    # kept beside the virtual environment (none in the checkout): each worker spent ~11 s of CPU
    # collecting the tests, rewriting every test module's asserts, 4 s with them kept (emptied as
    # the kernel cache; the first run writes it)
    local pycache="${TALUS_TEST_PYCACHE:-$VENV/talus-test-pycache}"
    if [ -d "$pycache" ] && [ "$(du -sm "$pycache" | cut -f1)" -gt 1024 ]; then
        log "emptying the bytecode cache $pycache (over 1 GiB)"
        rm -rf "$pycache"
    fi
    unset PYTHONDONTWRITEBYTECODE
    export QT_QPA_PLATFORM=xcb PYTHONPYCACHEPREFIX="$pycache"
    # one BLAS/OpenMP thread: the tests' many small matrix products and SVDs (200x200) ran 14-40x
    # slower, at 20-50x the CPU time, with a thread per core on a loaded 2-core machine
    export OPENBLAS_NUM_THREADS="${OPENBLAS_NUM_THREADS:-1}" OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}"
    export MKL_NUM_THREADS="${MKL_NUM_THREADS:-1}"

    log "ruff check ."
    "$VENV/bin/ruff" check . || status=$?
    log "lint-imports (import contracts in pyproject.toml)"
    "$VENV/bin/lint-imports" || status=$?

    # with no pytest options the tests run in $TALUS_TEST_WORKERS processes (pytest-xdist, default
    # 2; 1 = one process): tests/conftest.py keeps a file's tests, the files sharing an expensive
    # session fixture, and every GUI test (one X display) in one worker
    local workers="${TALUS_TEST_WORKERS:-2}"
    if [ "$#" -eq 0 ] && [ "$workers" -gt 1 ]; then
        set -- -n "$workers" --dist loadgroup
    fi
    log "pytest $*"
    local pytest_status=0
    if command -v xvfb-run >/dev/null 2>&1; then
        xvfb-run -a -s "$XVFB_SCREEN" "$VENV/bin/python" -m pytest -q "$@" || pytest_status=$?
    else
        log "warning: xvfb-run not found; GUI tests run only if a display is available"
        "$VENV/bin/python" -m pytest -q "$@" || pytest_status=$?
    fi
    [ "$pytest_status" -ne 0 ] && status=$pytest_status
    if [ "$status" -eq 0 ]; then log "all checks passed"; else log "FAILED (exit $status)"; fi
    return "$status"
}

cmd_lock() {
    [ $# -eq 0 ] || die "lock takes no arguments, got: $*"
    local tmp venv out
    tmp="$(mktemp -d "${TMPDIR:-/tmp}/talus-lock.XXXXXX")"
    # shellcheck disable=SC2064  # expand now: the path is fixed
    trap "rm -rf '$tmp'" EXIT
    venv="$tmp/venv"
    make_venv "$venv"
    log "installing talus-biplane[test] from the ranges in pyproject.toml (no constraints)"
    # the pip configuration of this machine (index, find-links) applies as for any install
    "$venv/bin/python" -m pip install -q -e "$ROOT[test]" >&2
    out="$tmp/constraints.txt"
    {
        echo "# Exact versions of every dependency of talus-biplane[test] (which includes [gui]),"
        echo "# resolved from the ranges in pyproject.toml by \`bash installer/dev.sh lock\`."
        echo "# Made $(date -u +%Y-%m-%d) with Python $("$venv/bin/python" -c 'import platform, sys; print(platform.python_version(), "on", sys.platform, platform.machine())')."
        echo "# installer/dev.sh installs with \`pip install -c\` this file; README says when to refresh it."
        "$venv/bin/python" -m pip freeze --exclude-editable
    } >"$out"
    if grep -q ' @ ' "$out"; then
        grep ' @ ' "$out" >&2
        die "pip freeze gave direct references (above), which a constraints file cannot hold"
    fi
    # atomic: a crash leaves the old file or the new one, never half of it
    cp "$out" "$LOCK.tmp.$$"
    mv -f "$LOCK.tmp.$$" "$LOCK"
    log "wrote ${LOCK#"$ROOT/"} ($(grep -c '==' "$LOCK") packages); review with git diff, then run the tests"
}

main() {
    local cmd="${1:-}"
    [ $# -gt 0 ] && shift
    case "$cmd" in
        demo) cmd_demo "$@" ;;
        test) cmd_test "$@" ;;
        gui) cmd_gui "$@" ;;
        lock) cmd_lock "$@" ;;
        bundle) ensure_venv; pip_install gui; exec bash "$ROOT/installer/build.sh" bundle "$@" ;;
        -h|--help|help) usage ;;
        *) usage; die "unknown command '${cmd}' (expected demo, test, gui, lock or bundle)" ;;
    esac
}

main "$@"
