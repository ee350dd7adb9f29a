#!/usr/bin/env bash
# Installs the built bundle's menu entry for the current user (no root needed):
#   ~/.local/bin/motion-composer                                  -> this folder's program
#   ~/.local/share/applications/motion-composer.desktop
#   ~/.local/share/icons/hicolor/256x256/apps/motion-composer.png
# Run it from the bundle (dist/motion-composer/install-desktop-entry.sh); the bundle must stay
# where it is (the command is a link to it). --uninstall removes the three again.
# PREFIX=/usr/local (as root) installs for everyone instead.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
prefix=${PREFIX:-$HOME/.local}
bin=$prefix/bin/motion-composer
desktop=$prefix/share/applications/motion-composer.desktop
icon=$prefix/share/icons/hicolor/256x256/apps/motion-composer.png

if [ "${1:-}" = "--uninstall" ]; then
  rm -f "$bin" "$desktop" "$icon"
  echo "removed $bin, $desktop, $icon"
else
  for f in motion-composer motion-composer.desktop motion-composer.png; do
    [ -e "$here/$f" ] || { echo "install: $here/$f is missing (run this from the built bundle)" >&2; exit 1; }
  done
  mkdir -p "$(dirname "$bin")" "$(dirname "$desktop")" "$(dirname "$icon")"
  ln -sfn "$here/motion-composer" "$bin"
  install -m 644 "$here/motion-composer.desktop" "$desktop"
  install -m 644 "$here/motion-composer.png" "$icon"
  echo "installed $bin -> $here/motion-composer, $desktop and $icon"
  case ":$PATH:" in *":$prefix/bin:"*) ;; *) echo "note: $prefix/bin is not on PATH; add it so that the menu entry's 'motion-composer' is found" ;; esac
fi
command -v update-desktop-database >/dev/null 2>&1 && update-desktop-database -q "$(dirname "$desktop")" || true
command -v gtk-update-icon-cache >/dev/null 2>&1 && gtk-update-icon-cache -q -t "$prefix/share/icons/hicolor" || true
