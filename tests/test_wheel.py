"""The wheel, as a user gets it: built from a copy of the sources, installed with its ``gui``
extra into a fresh venv in a temporary folder (no editable paths or site-packages inherited
from the tests' own environment), then run from another folder: ``motion-composer info`` on a
bundled clip, ``retarget`` of one bundled clip onto another, ``python -m motion_composer``,
``--self-test`` and ``--demo --screenshot`` under Xvfb. In that venv only ``motion_composer``
imports; ``app`` and ``engine`` do not.

Slow (a minute or two: the build, then pip installing numpy, scipy and PySide6 from the
package index pip uses here). pip's network problems skip with their reason; every step has
a bounded timeout.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from conftest import REPO

pytestmark = pytest.mark.slow

#: what the wheel must carry besides the code, under motion_composer/resources/
RESOURCES = ("demo/demo.mcp", "clips/cmu_131_01_walk.bvh", "clips/cmu_rest_tpose.bvh",
             "clips/fair1_child8_jumping.bvh", "clips/NOTICE.md",
             "characters/test_character.glb", "characters/NOTICE.md",
             "icons/motion-composer.png")
#: what the sources' copy needs to build (motion_composer/ holds symlinks to the others)
SOURCES = ("pyproject.toml", "README.md", "LICENSE", "motion_composer", "app", "engine",
           "resources")
#: longest wait for pip (build, install) and for a run of the program [s]
PIP_TIMEOUT_S = 900
RUN_TIMEOUT_S = 300
#: words in pip's output that mean the package index could not be reached
NETWORK_TROUBLE = ("Could not fetch URL", "Max retries exceeded", "Temporary failure in name",
                   "Connection refused", "Network is unreachable", "timed out",
                   "No matching distribution found")


def _clean_env(tmp: Path) -> dict:
    """An environment that leads to nothing of the tests' own installation."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV", "PYTHONSTARTUP")}
    env.update(PYTHONNOUSERSITE="1", HOME=str(tmp / "home"), XDG_CONFIG_HOME=str(tmp / "config"),
               XDG_STATE_HOME=str(tmp / "state"), XDG_CACHE_HOME=str(tmp / "cache"))
    (tmp / "home").mkdir(exist_ok=True)
    return env


def _pip(args: list[str], env: dict, what: str) -> None:
    """Run pip; skip on network trouble or a timeout, fail on anything else."""
    try:
        proc = subprocess.run(args, capture_output=True, text=True, env=env,
                              timeout=PIP_TIMEOUT_S, stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired:
        pytest.skip(f"{what}: pip took more than {PIP_TIMEOUT_S} s (a slow package index?)")
    if proc.returncode != 0:
        out = proc.stdout + proc.stderr
        if any(word in out for word in NETWORK_TROUBLE):
            pytest.skip(f"{what}: pip could not reach its package index: {out[-600:]}")
        pytest.fail(f"{what} failed:\n{out[-4000:]}")


def _copy_sources(dest: Path) -> None:
    """The files a build needs, symlinks kept as symlinks (as git checks them out)."""
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info")
    for name in SOURCES:
        src = REPO / name
        if src.is_dir():
            shutil.copytree(src, dest / name, symlinks=True, ignore=ignore)
        else:
            shutil.copy2(src, dest / name)


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """``(venv python, venv bin, environment, folder to run in, the wheel)``."""
    tmp = tmp_path_factory.mktemp("wheel")
    env = _clean_env(tmp)
    src = tmp / "src"
    src.mkdir()
    _copy_sources(src)
    dist = tmp / "dist"
    _pip([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(dist), str(src)],
         env, "building the wheel")
    [wheel] = dist.glob("motion_composer-*.whl")
    venv = tmp / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, env=env,
                   timeout=RUN_TIMEOUT_S)
    python = venv / "bin" / "python"
    _pip([str(python), "-m", "pip", "install", "-q", f"{wheel}[gui]"], env,
         "installing the wheel with its gui extra")
    elsewhere = tmp / "elsewhere"
    elsewhere.mkdir()
    return python, venv / "bin", env, elsewhere, wheel


def _run(installed, *args, timeout=RUN_TIMEOUT_S) -> subprocess.CompletedProcess:
    _, _, env, elsewhere, _ = installed
    return subprocess.run(list(map(str, args)), capture_output=True, text=True, cwd=elsewhere,
                          env=env, timeout=timeout, stdin=subprocess.DEVNULL)


def _resources(installed) -> Path:
    python = installed[0]
    out = _run(installed, python, "-c", "import motion_composer, pathlib; "
               "print(pathlib.Path(motion_composer.__file__).parent / 'resources')")
    assert out.returncode == 0, out.stderr
    return Path(out.stdout.strip())


def test_the_wheel_holds_one_package_its_resources_and_the_license(installed):
    wheel = installed[4]
    names = zipfile.ZipFile(wheel).namelist()
    tops = {n.split("/", 1)[0] for n in names}
    assert tops == {"motion_composer", wheel.name.split("-py3")[0] + ".dist-info"}, tops
    for res in RESOURCES:
        assert f"motion_composer/resources/{res}" in names, res
    assert "motion_composer/engine/__init__.py" in names
    assert "motion_composer/app/cli.py" in names and "motion_composer/__main__.py" in names
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names)
    entry = next(n for n in names if n.endswith("entry_points.txt"))
    assert "motion-composer = motion_composer.app.cli:main" in \
        zipfile.ZipFile(wheel).read(entry).decode()


def test_only_motion_composer_imports_in_the_venv(installed):
    python, _, _, elsewhere, _ = installed
    for name in ("app", "engine"):
        result = _run(installed, python, "-c", f"import {name}")
        assert result.returncode != 0 and "ModuleNotFoundError" in result.stderr, name
    result = _run(installed, python, "-c", "import motion_composer, motion_composer.engine, "
                  "motion_composer.app.cli; print(motion_composer.__version__, "
                  "motion_composer.engine.__file__)")
    assert result.returncode == 0, result.stderr
    version, engine_file = result.stdout.split()
    assert version == "0.1.0"
    assert Path(engine_file).is_relative_to(python.parent.parent), engine_file
    resources = _resources(installed)
    assert resources.is_relative_to(python.parent.parent) and not resources.is_symlink()
    assert (resources / "demo" / "demo.mcp").is_file()


def test_the_commands_work_from_another_folder(installed):
    python, bin_dir, _, elsewhere, _ = installed
    clips = _resources(installed) / "clips"
    info = _run(installed, bin_dir / "motion-composer", "info", clips / "cmu_131_01_walk.bvh",
                "--json")
    assert info.returncode == 0, info.stderr
    assert json.loads(info.stdout)["frames"] == 994
    out = elsewhere / "walk_on_child.bvh"
    retarget = _run(installed, bin_dir / "motion-composer", "retarget",
                    clips / "cmu_131_01_walk.bvh", "--target",
                    clips / "fair1_child8_jumping.bvh", "-o", out)
    assert retarget.returncode == 0, retarget.stderr
    back = _run(installed, bin_dir / "motion-composer", "info", out, "--json")
    assert back.returncode == 0 and json.loads(back.stdout)["frames"] == 994, back.stderr
    helped = _run(installed, python, "-m", "motion_composer", "--help")
    assert helped.returncode == 0 and "retarget" in helped.stdout and "--demo" in helped.stdout
    bad = _run(installed, bin_dir / "motion-composer", "info", elsewhere / "absent.bvh")
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1


def test_the_window_self_tests_and_opens_the_demo_under_xvfb(installed):
    xvfb = shutil.which("xvfb-run")
    if xvfb is None:
        pytest.skip("xvfb-run is not installed (Debian: apt-get install xvfb xauth): the "
                    "installed window's self-test needs a display")
    _, bin_dir, _, elsewhere, _ = installed
    headless = [xvfb, "-a", "-s", "-screen 0 1600x1000x24"]
    result = _run(installed, *headless, bin_dir / "motion-composer", "--self-test")
    lines = [line for line in result.stdout.splitlines() if line.startswith("self-test: ")]
    assert result.returncode == 0 and lines and lines[0].startswith("self-test: ok (demo 994"), \
        result.stdout[-2000:] + result.stderr[-2000:]
    assert "skinned target test_character.glb" in lines[0], lines[0]
    picture = elsewhere / "demo-window.png"
    demo = _run(installed, *headless, bin_dir / "motion-composer", "--demo",
                "--screenshot", picture)
    assert demo.returncode == 0, demo.stderr[-2000:]
    assert picture.is_file() and picture.stat().st_size > 1000
    missing = _run(installed, *headless, bin_dir / "motion-composer", elsewhere / "absent.mcp",
                   "--screenshot", elsewhere / "never.png")
    assert missing.returncode == 2 and "no such project file" in missing.stderr
