#!/usr/bin/env bash
# Build the Talus distributions.
#
#   bash installer/build.sh wheel    wheel + sdist into dist/ (setuptools, the project's build backend)
#   bash installer/build.sh icons    redraw resources/icons/talus.png and derive the .ico/.icns from it
#   bash installer/build.sh bundle   standalone folder dist/talus/ (PyInstaller): Python, Qt, VTK, Warp,
#                                    the `talus` command, talus.desktop, talus.png, install-desktop.sh;
#                                    and dist/talus-<version>-linux-x86_64.tar.gz
#   bash installer/build.sh smoke    start the bundle under Xvfb (demo study opened, window closed),
#                                    then a CUDA-free `talus demo --no-gui` at 64 px, 2 frames
#
# Uses the development venv (.venv or $TALUS_VENV; `bash installer/dev.sh demo` makes it) and installs
# PyInstaller there at the pinned version below. The bundle is built for the machine it runs on
# (Linux here; the same spec on Windows/macOS, see installer/README.md). Build work goes to
# build/pyinstaller (or $TALUS_BUILD_DIR); set TALUS_DIST to put the results elsewhere than dist/.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${TALUS_VENV:-$ROOT/.venv}"
DIST="${TALUS_DIST:-$ROOT/dist}"
WORK="${TALUS_BUILD_DIR:-$ROOT/build/pyinstaller}"
# PyInstaller and its community hooks (Qt, VTK, imagecodecs, SimpleITK...), pinned together
PYINSTALLER_PINS=(pyinstaller==6.22.3 pyinstaller-hooks-contrib==2026.9)

log() { printf '[build.sh] %s\n' "$*" >&2; }
die() { log "error: $*"; exit 1; }
usage() { sed -n '2,/^set -euo/{/^#/p}' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2; }

need_venv() {
    [ -x "$VENV/bin/python" ] || die "no virtual environment at $VENV: run 'bash installer/dev.sh demo' first (or set TALUS_VENV)"
}

version() { "$VENV/bin/python" -c 'import core; print(core.__version__)'; }

cmd_wheel() {
    need_venv
    mkdir -p "$DIST"
    log "wheel (pip wheel --no-deps) into ${DIST#"$ROOT/"}"
    "$VENV/bin/python" -m pip wheel -q --no-deps -w "$DIST" "$ROOT" >&2
    log "sdist (setuptools.build_meta.build_sdist) into ${DIST#"$ROOT/"}"
    (cd "$ROOT" && "$VENV/bin/python" -c 'import sys; from setuptools import build_meta as b; print(b.build_sdist(sys.argv[1]))' "$DIST") >&2
    ls -l "$DIST"/talus[-_]biplane-* >&2
}

cmd_icons() {
    need_venv
    "$VENV/bin/python" "$ROOT/installer/make_icons.py" "$@"
}

cmd_bundle() {
    need_venv
    if ! "$VENV/bin/python" -m PyInstaller --version 2>/dev/null | grep -qx "${PYINSTALLER_PINS[0]#*==}"; then
        log "installing ${PYINSTALLER_PINS[*]} into $VENV"
        "$VENV/bin/python" -m pip install -q "${PYINSTALLER_PINS[@]}" >&2
    fi
    local out="$DIST/talus" ver start
    ver="$(version)"
    start=$(date +%s)
    log "PyInstaller $("$VENV/bin/python" -m PyInstaller --version) -> ${out#"$ROOT/"} (several minutes)"
    "$VENV/bin/python" -m PyInstaller --noconfirm --clean --log-level WARN \
        --distpath "$DIST.partial" --workpath "$WORK" "$ROOT/installer/talus.spec" >&2
    # the launcher files beside the executable
    cp "$ROOT/app/icons/talus.png" "$DIST.partial/talus/talus.png"
    cp "$ROOT/installer/talus.desktop" "$DIST.partial/talus/talus.desktop"
    cat >"$DIST.partial/talus/install-desktop.sh" <<'SH'
#!/bin/sh
# Add Talus to the desktop's application menu (for this user), pointing at this folder.
set -e
here="$(cd "$(dirname "$0")" && pwd)"
apps="${XDG_DATA_HOME:-$HOME/.local/share}/applications"
mkdir -p "$apps"
sed "s|@BUNDLE@|$here|g" "$here/talus.desktop" > "$apps/talus.desktop.tmp"
mv "$apps/talus.desktop.tmp" "$apps/talus.desktop"
echo "installed $apps/talus.desktop (Exec=$here/talus gui)"
SH
    chmod +x "$DIST.partial/talus/install-desktop.sh"
    # atomic: a failed build never leaves a half bundle at dist/talus
    rm -rf "$out"
    mkdir -p "$DIST"
    mv "$DIST.partial/talus" "$out"
    rm -rf "$DIST.partial"
    log "bundle: ${out#"$ROOT/"} $(du -sh "$out" | cut -f1) in $(( $(date +%s) - start )) s"
    local tarball="$DIST/talus-$ver-linux-$(uname -m).tar.gz"
    tar -C "$DIST" -czf "$tarball.tmp" talus && mv "$tarball.tmp" "$tarball"
    log "archive: ${tarball#"$ROOT/"} $(du -sh "$tarball" | cut -f1)"
}

cmd_smoke() {
    local bundle="${1:-$DIST/talus}"
    [ -x "$bundle/talus" ] || die "no bundle at $bundle (expected $bundle/talus): run 'bash installer/build.sh bundle' first"
    exec bash "$ROOT/installer/smoke_bundle.sh" "$bundle"
}

main() {
    local cmd="${1:-}"
    [ $# -gt 0 ] && shift
    case "$cmd" in
        wheel) cmd_wheel "$@" ;;
        icons) cmd_icons "$@" ;;
        bundle) cmd_bundle "$@" ;;
        smoke) cmd_smoke "$@" ;;
        -h|--help|help) usage ;;
        *) usage; die "unknown command '${cmd}' (expected wheel, icons, bundle or smoke)" ;;
    esac
}

main "$@"
