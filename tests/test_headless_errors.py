"""The window with no one to answer a dialog (``--screenshot``, or no screen: Qt's offscreen
platform): a project that does not load prints one line on stderr and exits 2, instead of
opening a modal dialog that nothing can close."""
from __future__ import annotations

import os
import subprocess
import sys

from conftest import REPO

#: the command line's exit code for an error the user can fix
EXIT_USER_ERROR = 2


def _window(tmp_path, *args, **env_extra) -> subprocess.CompletedProcess:
    env = dict(os.environ, **env_extra)
    env["XDG_CONFIG_HOME"] = str(tmp_path / "config")          # leave the user's alone
    env["XDG_STATE_HOME"] = str(tmp_path / "state")
    env["PYTHONPATH"] = str(REPO)                              # these sources, from anywhere
    # from another folder: nothing may depend on the current directory
    return subprocess.run([sys.executable, "-m", "motion_composer.app.cli", *args], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=60,
                          stdin=subprocess.DEVNULL)


def _our_lines(stderr: str) -> list[str]:
    """Our lines on stderr (Qt adds its own warnings on the offscreen platform)."""
    return [line for line in stderr.splitlines() if line.startswith("motion-composer:")]


def test_a_missing_project_with_screenshot_is_one_line_and_exit_2(tmp_path):
    picture = tmp_path / "window.png"
    result = _window(tmp_path, str(tmp_path / "absent.mcp"), "--screenshot", str(picture))
    assert result.returncode == EXIT_USER_ERROR, result.stderr[-2000:]
    lines = _our_lines(result.stderr)
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("motion-composer: error: ") and "absent.mcp" in lines[0]
    assert "no such project file" in lines[0]
    assert not picture.exists()


def test_a_broken_demo_without_a_screen_is_one_line_and_exit_2(tmp_path):
    corrupt = tmp_path / "corrupt.mcp"
    corrupt.write_text("{ this is not a project", encoding="utf-8")
    result = _window(tmp_path, "--demo", QT_QPA_PLATFORM="offscreen",
                     MC_DEMO_PROJECT=str(corrupt))
    assert result.returncode == EXIT_USER_ERROR, result.stderr[-2000:]
    lines = _our_lines(result.stderr)
    assert len(lines) == 1, result.stderr
    assert "corrupt.mcp" in lines[0]


def test_the_demo_screenshot_is_written_where_asked(tmp_path):
    picture = tmp_path / "demo-window.png"
    result = _window(tmp_path, "--demo", "--screenshot", str(picture))
    assert result.returncode == 0, result.stderr[-2000:]
    assert _our_lines(result.stderr) == []
    assert picture.is_file() and picture.stat().st_size > 1000
