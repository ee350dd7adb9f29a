#!/usr/bin/env bash
# Builds the desktop bundle, packaging/dist/motion-composer/ (PyInstaller, one folder), then
# checks the built program, away from the sources: its self-test headless under Xvfb (start,
# load the bundled demo, step frames, check the viewport drew, take the bundled skinned
# character as the target and check its mesh follows, quit) and command-line runs on
# the bundled clips and demo (info --json, retarget with IK, export --solve, batch in two
# worker processes). Fails loudly if any check fails; prints the self-test's line, the
# bundle's size and the time taken.
#   bash packaging/build.sh                 # a clean build venv (packaging/.venv-build)
#   bash packaging/build.sh --reuse-venv    # keep that venv if it exists (faster)
# Needs: Python 3.10+ with venv and a shared libpython (Debian's python3 and python3-venv;
# PYTHON=... picks another), PyPI, and for the checks Xvfb and Qt's X11 libraries (the system
# packages `bash scripts/setup.sh` installs).
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
repo=$(dirname "$here")
venv=$here/.venv-build
dist=$here/dist
bundle=$dist/motion-composer
python=${PYTHON:-python3}
started=$(date +%s)

say() { echo "build: $*"; }
die() { echo "build: FAILED: $*" >&2; exit 1; }

reuse=0
[ "${1:-}" = "--reuse-venv" ] && reuse=1

# the check needs a display: Xvfb, or the one we are on
if command -v xvfb-run >/dev/null 2>&1; then
  headless=(xvfb-run -a -s "-screen 0 1600x1000x24")
elif [ -n "${DISPLAY:-}" ]; then
  headless=()
  say "xvfb-run not found; the self-test runs on DISPLAY=$DISPLAY"
else
  die "no xvfb-run and no DISPLAY: install Xvfb (apt-get install xvfb xauth, or bash scripts/setup.sh)"
fi

# 1. a build venv with the project (gui extra) and PyInstaller
if [ "$reuse" = 0 ] || [ ! -x "$venv/bin/python" ]; then
  say "creating a clean build venv in $venv"
  rm -rf "$venv"
  "$python" -m venv "$venv" || die "'$python -m venv' failed (Debian: apt-get install python3-venv)"
fi
"$venv/bin/python" -c 'import sysconfig, sys; sys.exit(0 if sysconfig.get_config_var("Py_ENABLE_SHARED") else 1)' \
  || die "$python has no shared libpython, which PyInstaller needs (use Debian's python3, or a Python built with --enable-shared; PYTHON=... selects it)"
"$venv/bin/python" -m pip install -q --upgrade pip
say "installing the project with its gui extra, and PyInstaller"
had_build=0
[ -e "$repo/build" ] && had_build=1
"$venv/bin/python" -m pip install -q "$repo[gui]" "pyinstaller>=6.3" \
  || die "pip could not install the project or PyInstaller"
# pip builds the project in the source tree: remove the build folder it left there
[ "$had_build" = 1 ] || rm -rf "$repo/build"

# 2. the bundle
say "running PyInstaller ($("$venv/bin/pyinstaller" --version))"
rm -rf "$bundle"
(cd "$here" && "$venv/bin/pyinstaller" --noconfirm --clean --log-level WARN \
   --distpath "$dist" --workpath "$here/build" motion-composer.spec) \
  || die "PyInstaller failed (see above)"
[ -x "$bundle/motion-composer" ] || die "PyInstaller made no $bundle/motion-composer"
# the Python library and its extension modules may carry debug information (a Python built
# from source does: 30 MB); the wheels' libraries are stripped already and are left alone
if command -v strip >/dev/null 2>&1; then
  find "$bundle/_internal" -maxdepth 1 -name 'libpython*.so*' -type f \
       -exec strip --strip-debug {} + || true
  find "$bundle/_internal" -path '*/lib-dynload/*.so' -type f -exec strip --strip-debug {} + || true
fi
install -m 644 "$here/motion-composer.desktop" "$bundle/motion-composer.desktop"
install -m 644 "$repo/resources/icons/motion-composer.png" "$bundle/motion-composer.png"
install -m 755 "$here/install-desktop-entry.sh" "$bundle/install-desktop-entry.sh"
if command -v desktop-file-validate >/dev/null 2>&1; then
  desktop-file-validate "$bundle/motion-composer.desktop" || die "the .desktop file is invalid"
fi

# 3. the built program's checks, away from the sources (it must use its own resources) and
#    with a scratch home (no trace in the user's settings)
scratch=$(mktemp -d)
trap 'rm -rf "$scratch"' EXIT
run_built() {
  (cd "$scratch" && env -u PYTHONPATH -u PYTHONHOME HOME="$scratch" "$@")
}
say "self-test of the built program (headless)"
set +e
run_built "${headless[@]}" "$bundle/motion-composer" --self-test >"$scratch/self-test.out" 2>&1
code=$?
set -e
line=$(grep '^self-test: ' "$scratch/self-test.out" || true)
if [ "$code" != 0 ] || [[ "$line" != "self-test: ok ("* ]]; then
  cat "$scratch/self-test.out" >&2
  die "the built program's self-test failed (exit code $code)"
fi
if [[ "$line" != *"target pixels"* ]]; then
  cat "$scratch/self-test.out" >&2
  die "the built program's viewport was not checked: no OpenGL under Xvfb (${line#self-test: })"
fi
if [[ "$line" != *"skinned target"*"followed the motion"* ]]; then
  cat "$scratch/self-test.out" >&2
  die "the built program's self-test did not check a skinned target (${line#self-test: })"
fi
echo "$line"

say "command line of the built program on the bundled clips and demo"
clip=$(find "$bundle" -path '*/resources/clips/cmu_131_01_walk.bvh' | head -n 1)
[ -n "$clip" ] || die "the bundle holds no resources/clips/cmu_131_01_walk.bvh"
run_built "$bundle/motion-composer" info "$clip" --json >"$scratch/info.json" \
  || die "'motion-composer info $clip --json' failed"
frames=$("$venv/bin/python" -c 'import json, sys; print(json.load(open(sys.argv[1]))["frames"])' \
  "$scratch/info.json") || die "'motion-composer info --json' printed no JSON"
[ "$frames" = 994 ] || die "'motion-composer info' says $frames frames, not 994"
echo "info: $(basename "$clip"): $frames frames"
# the engine with inverse kinematics (automatic foot contacts), and a project solved again
run_built "$bundle/motion-composer" retarget "$clip" --target "$(dirname "$clip")/fair1_child8_jumping.bvh" \
  -o "$scratch/retargeted.bvh" --auto-contacts || die "'motion-composer retarget' failed"
run_built "$bundle/motion-composer" export "$(dirname "$clip")/../demo/demo.mcp" \
  -o "$scratch/demo.bvh" --solve || die "'motion-composer export --solve' failed"
# batch: the demo's rules over two clips in two worker processes (multiprocessing, frozen)
cp "$clip" "$scratch/walk_a.bvh" && cp "$clip" "$scratch/walk_b.bvh"
run_built "$bundle/motion-composer" batch "$(dirname "$clip")/../demo/demo.mcp" \
  "$scratch/walk_a.bvh" "$scratch/walk_b.bvh" -o "$scratch/batch" --workers 2 2>/dev/null \
  || die "'motion-composer batch' with two worker processes failed"

size=$(du -sh "$bundle" | cut -f1)
say "ok: $bundle ($size, $(find "$bundle" -type f | wc -l) files) in $(( $(date +%s) - started )) s"
