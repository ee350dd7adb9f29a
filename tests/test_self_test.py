"""``motion-composer --self-test``: the check the desktop bundle's build runs on the built
program (start, load the demo, step frames, check the viewport drew, quit), here run on the
sources, and the resource paths it relies on both from the source tree and frozen."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

from conftest import REPO


def _self_test(tmp_path, **env_extra) -> subprocess.CompletedProcess:
    env = dict(os.environ, **env_extra)
    # the test session's display (pytest-xvfb sets DISPLAY); without one, Qt's offscreen
    # platform (the self-test then says it could not check the viewport's drawing)
    if not env.get("DISPLAY") and not env.get("WAYLAND_DISPLAY"):
        env["QT_QPA_PLATFORM"] = "offscreen"
    env["XDG_CONFIG_HOME"] = str(tmp_path / "config")          # leave the user's alone
    return subprocess.run([sys.executable, "-m", "motion_composer.app.cli", "--self-test"], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=90)


def _line(out: str) -> str:
    lines = [line for line in out.splitlines() if line.startswith("self-test: ")]
    assert len(lines) == 1, out
    return lines[0]


def test_the_self_test_loads_the_demo_steps_frames_and_passes(tmp_path):
    result = _self_test(tmp_path)
    line = _line(result.stdout)
    assert result.returncode == 0, (line, result.stderr[-2000:])
    assert line.startswith("self-test: ok (demo 994 frames"), line
    stepped = int(re.search(r"stepped (\d+) frames", line).group(1))
    assert stepped >= 60
    if os.environ.get("DISPLAY"):
        # an X server (Xvfb with Mesa here): the viewport must really have drawn
        pixels = re.search(r"drew (\d+) target pixels", line)
        assert pixels and int(pixels.group(1)) >= 100, line
    # then a skinned target: the bundled test character, whose mesh follows the motion
    assert "skinned target test_character.glb (480 vertices, 31 joints) followed the motion" \
        in line, line


def test_a_broken_demo_fails_the_self_test_with_its_reason(tmp_path):
    corrupt = tmp_path / "corrupt.mcp"
    corrupt.write_text('{"format": "motion-composer-project", "version": 1, "performer": ')
    result = _self_test(tmp_path, MC_DEMO_PROJECT=str(corrupt))
    assert result.returncode == 1
    line = _line(result.stdout)
    assert line.startswith("self-test: FAILED: the demo project did not open: "), line
    assert "corrupt.mcp" in line and "not valid JSON" in line

    result = _self_test(tmp_path, MC_DEMO_PROJECT=str(tmp_path / "absent.mcp"))
    assert result.returncode == 1
    assert _line(result.stdout) == (f"self-test: FAILED: the demo project is missing: "
                                    f"{tmp_path / 'absent.mcp'}")


def test_the_command_line_passes_the_self_test_option(monkeypatch):
    import motion_composer.app.cli
    import motion_composer.app.gui.main
    calls = []
    monkeypatch.setattr(motion_composer.app.gui.main, "run", lambda *a, **k: calls.append((a, k)) or 0)
    assert motion_composer.app.cli.main(["--self-test"]) == 0
    assert calls == [((), {"self_test": True})]


def test_resources_are_found_from_the_sources_and_in_the_bundle(monkeypatch, tmp_path):
    from motion_composer.app.resources import is_frozen, resource_path
    assert not is_frozen()
    assert resource_path("demo/demo.mcp") == REPO / "resources" / "demo" / "demo.mcp"
    assert resource_path("icons/motion-composer.png").is_file()
    # PyInstaller sets sys.frozen and sys._MEIPASS (the bundle's _internal folder)
    monkeypatch.setattr(sys, "frozen", True, raising=False)
    monkeypatch.setattr(sys, "_MEIPASS", str(tmp_path), raising=False)
    assert is_frozen()
    assert resource_path("demo/demo.mcp") == Path(tmp_path) / "resources" / "demo" / "demo.mcp"


def test_the_window_uses_the_bundled_demo_and_icon(monkeypatch):
    import motion_composer.app.gui.main as main
    assert main.DEMO_PROJECT == REPO / "resources" / "demo" / "demo.mcp"
    assert main.DEMO_PROJECT.is_file() and main.ICON.is_file()
    monkeypatch.setenv("MC_DEMO_PROJECT", "/elsewhere/x.mcp")
    assert main.demo_project() == Path("/elsewhere/x.mcp")
    monkeypatch.delenv("MC_DEMO_PROJECT")
    assert main.demo_project() == main.DEMO_PROJECT
