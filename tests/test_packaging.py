"""What a wheel of msarm carries: every package, and the robot models inside the package."""

from __future__ import annotations

import shutil
import subprocess
import sys
import sysconfig
import tomllib
import zipfile
from pathlib import Path

import pytest

from msarm.compensation.pipeline import CompensatorRecipe
from msarm.io.config import load_config
from msarm.model import MODELS_DIR, _models_dir

ROOT = Path(__file__).resolve().parent.parent


def test_every_package_is_listed_in_pyproject():
    settings = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    inits = (ROOT / "msarm").rglob("__init__.py")
    found = {".".join(init.parent.relative_to(ROOT).parts) for init in inits}
    listed = set(settings["packages"])
    assert listed == found | {"msarm.models"}


def test_the_models_are_found_inside_the_package_or_beside_it(tmp_path):
    package = tmp_path / "msarm"
    package.mkdir()
    assert _models_dir(package) == tmp_path / "models"  # a source checkout
    (package / "models").mkdir()
    assert _models_dir(package) == package / "models"  # an installed wheel
    assert MODELS_DIR == ROOT / "models"  # this checkout


def test_the_recipe_defaults_are_the_shipped_recipe():
    """`msarm train` without training/compensator.yaml (an installed wheel) runs its defaults."""
    assert load_config(ROOT / "training/compensator.yaml", CompensatorRecipe) == CompensatorRecipe()


def test_a_wheel_carries_the_models_and_loads_them(tmp_path):
    wheels, target, source = tmp_path / "wheels", tmp_path / "site", tmp_path / "source"
    # a copy of what the wheel is made of: setuptools writes build/ into the tree it builds
    skip = shutil.ignore_patterns("__pycache__", "*.egg-info", "build")
    for part in ("msarm", "models"):
        shutil.copytree(ROOT / part, source / part, ignore=skip)
    for part in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / part, source / part)
    build = [sys.executable, "-m", "pip", "--disable-pip-version-check"]
    wheel_options = ["--no-deps", "--no-build-isolation", "-q", "-w", str(wheels)]
    built = subprocess.run(
        [*build, "wheel", *wheel_options, str(source)],
        capture_output=True,
        text=True,
    )
    if built.returncode != 0:
        pytest.skip(f"no wheel could be built here: {built.stderr.strip()[-300:]}")
    (wheel,) = wheels.glob("msarm-*.whl")
    with zipfile.ZipFile(wheel) as archive:
        for name in ("msarm_arm.xml", "ipanema_mini.xml"):
            assert archive.read(f"msarm/models/{name}") == (ROOT / "models" / name).read_bytes()
    subprocess.run(
        [*build, "install", "--no-deps", "-q", "--target", str(target), str(wheel)], check=True
    )
    # the installed copy alone, without this checkout's editable finder, in another folder
    script = (
        "import site, sys\n"
        f"site.addsitedir({sysconfig.get_paths()['purelib']!r})\n"
        "sys.meta_path[:] = [f for f in sys.meta_path if 'editable' not in repr(f)]\n"
        f"sys.path.insert(0, {str(target)!r})\n"
        "import msarm.model\n"
        "print(msarm.model.__file__)\n"
        "print(msarm.model.load_arm().sha256)\n"
    )
    command = [sys.executable, "-S", "-c", script]
    result = subprocess.run(command, capture_output=True, text=True, cwd=tmp_path, check=True)
    where, sha256 = result.stdout.split()
    assert Path(where).is_relative_to(target)
    from msarm.model import load_arm

    assert sha256 == load_arm().sha256
