"""What a wheel of msarm carries: every package, and the robot models inside the package."""

from __future__ import annotations

import ast
import re
import shutil
import subprocess
import sys
import sysconfig
import tomllib
import zipfile
from importlib.metadata import packages_distributions
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


def _normalised(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def test_every_library_msarm_imports_is_a_declared_dependency():
    """`pip install msarm` must bring what msarm imports: daqp (the allocation's QP solver)
    was only in requirements.lock, and an install by pip's own resolution failed on the first
    allocation with ModuleNotFoundError."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    declared = {_normalised(re.split(r"[<>=!~ ;\[]", d)[0]) for d in project["dependencies"]}
    imported = set()
    for path in (ROOT / "msarm").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                imported |= {alias.name.split(".")[0] for alias in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                imported.add(node.module.split(".")[0])
    third_party = imported - set(sys.stdlib_module_names) - {"msarm", "__future__"}
    distributions = packages_distributions()
    distributions["pinocchio"] = ["pin"]  # the pin wheel puts it on the path through a .pth
    undeclared = {
        name: distributions.get(name)
        for name in third_party
        if not {_normalised(d) for d in distributions.get(name, [name])} & declared
    }
    assert not undeclared, f"imported but not in [project].dependencies: {undeclared}"


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
    for part in ("pyproject.toml", "README.md", "LICENSE"):
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
