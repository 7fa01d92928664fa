"""The wheel: built from this checkout and installed into a fresh virtual environment, offline, its
console scripts work from any folder — the Hydra configs ship inside it — and it installs no
top-level ``experiments`` package (which would collide with any other of that name)."""

from __future__ import annotations

import ast
import importlib.util
import os
import shutil
import site
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

ENV = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}  # only what the venv itself holds
SKIP = shutil.ignore_patterns(".git", ".venv", "outputs", "multirun", "build", "dist", "*.egg-info",
                              "__pycache__", ".pytest_cache", ".ipynb_checkpoints")


def _build_wheel(src: Path, dist: Path) -> Path:
    """``python -m build --wheel --no-isolation`` (pip's wheel builder where ``build`` is missing):
    no network, the installed setuptools."""
    if importlib.util.find_spec("build") is not None:
        cmd = [sys.executable, "-m", "build", "--wheel", "--no-isolation", "--outdir", str(dist), str(src)]
    else:
        cmd = [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-w", str(dist), str(src)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    (wheel,) = dist.glob("somtorch-*.whl")
    return wheel


def test_experiments_import_each_other_relatively():
    """In a wheel the package is somtorch_experiments: an absolute ``experiments.`` import breaks it."""
    bad = []
    for path in sorted((ROOT / "experiments").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                     [node.module or ""] if isinstance(node, ast.ImportFrom) and node.level == 0 else [])
            bad += [f"{path.name}:{node.lineno}" for n in names if n == "experiments" or n.startswith("experiments.")]
        bad += [f"{path.name}: import_module" for line in path.read_text().splitlines()
                if "import_module(" in line and '"experiments.' in line]
    assert not bad, f"absolute imports of experiments (use from .module import ...): {bad}"


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """A fresh venv holding only the wheel; its dependencies (torch, Hydra, …) are read from this
    interpreter's site-packages through a .pth file, so nothing is downloaded."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    shutil.copytree(ROOT, src, ignore=SKIP)
    wheel = _build_wheel(src, tmp / "dist")
    venv = tmp / "venv"
    subprocess.run([sys.base_prefix + "/bin/python3", "-m", "venv", "--without-pip", str(venv)], check=True)
    purelib = next((venv / "lib").glob("python3*")) / "site-packages"
    (purelib / "zz_dependencies.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    proc = subprocess.run([str(venv / "bin" / "python"), "-m", "pip", "install", "-q", "--no-deps", "--no-index",
                           "--ignore-installed", "--no-warn-script-location", str(wheel)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    work = tmp / "elsewhere"  # not the checkout: nothing of it may be importable
    work.mkdir()
    return venv, purelib, work


@pytest.mark.slow
def test_the_wheel_installs_somtorch_experiments_with_its_configs(installed):
    venv, purelib, _ = installed
    assert (purelib / "somtorch").is_dir() and (purelib / "somtorch_experiments" / "conf" / "run.yaml").is_file()
    assert (purelib / "somtorch_experiments" / "conf" / "data" / "motorcycle.yaml").is_file()
    assert not (purelib / "experiments").exists()


@pytest.mark.slow
def test_somtorch_run_help_from_the_wheel(installed):
    venv, purelib, work = installed
    proc = subprocess.run([str(venv / "bin" / "somtorch-run"), "--help"], cwd=work, capture_output=True,
                          text=True, timeout=60, env=ENV)
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    assert out.startswith("somtorch-run [group=option ...] [key=value ...]")
    assert "  data: " in out and "motorcycle" in out and "  data.disparity_scale=None  — " in out
    code = ("import importlib.util, somtorch, somtorch_experiments as e; "
            "print(importlib.util.find_spec('experiments'), somtorch.__file__, e.CONF)")
    proc = subprocess.run([str(venv / "bin" / "python"), "-c", code], cwd=work, capture_output=True, text=True,
                          timeout=60, env=ENV)
    assert proc.returncode == 0, proc.stderr
    none, somtorch_file, conf = proc.stdout.split()[-3:]
    site_dir = purelib.resolve()
    assert none == "None"  # no top-level "experiments"
    assert Path(somtorch_file).resolve().is_relative_to(site_dir) and Path(conf).resolve().is_relative_to(site_dir)


@pytest.mark.slow
def test_somtorch_run_composes_its_config_from_the_wheel(installed):
    venv, _, work = installed
    proc = subprocess.run([str(venv / "bin" / "somtorch-run"), "--cfg", "job", "data=kitti2015"], cwd=work,
                          capture_output=True, text=True, timeout=120, env=ENV)
    assert proc.returncode == 0, proc.stderr
    assert "source: kitti2015" in proc.stdout or "kitti" in proc.stdout
