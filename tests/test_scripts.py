"""scripts/setup.sh: the stamp of installed extras (run.sh installs the base package, test.sh the
test extra) and its libusb check, run for real in a copy of the scripts with its own ``.venv``."""

from __future__ import annotations

import hashlib
import os
import shutil
import site
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.slow


@pytest.fixture
def checkout(tmp_path):
    """A copy of scripts/ and pyproject.toml whose ``.venv`` is a real venv that sees this
    interpreter's packages (a .pth file), so torch and somtorch import and pip installs into it."""
    if shutil.which("ldconfig") is None or "libusb-1.0.so.0" not in subprocess.run(
            ["ldconfig", "-p"], capture_output=True, text=True).stdout:
        pytest.skip("libusb-1.0 is not installed here: setup.sh would try apt-get")
    shutil.copytree(ROOT / "scripts", tmp_path / "scripts")
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    subprocess.run([sys.base_prefix + "/bin/python3", "-m", "venv", "--without-pip", str(tmp_path / ".venv")],
                   check=True)
    purelib = next((tmp_path / ".venv" / "lib").glob("python3*")) / "site-packages"
    (purelib / "parent.pth").write_text("\n".join([*site.getsitepackages(), str(ROOT)]) + "\n")
    return tmp_path


def _setup(root: Path, extra: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PIP_NO_INDEX": "1", "PIP_FIND_LINKS": "", "PIP_DISABLE_PIP_VERSION_CHECK": "1"}
    return subprocess.run(["bash", "scripts/setup.sh", extra], cwd=root, capture_output=True, text=True,
                          timeout=120, env=env)


def _stamp(root: Path, extras: str) -> None:
    digest = hashlib.sha256((root / "pyproject.toml").read_bytes()).hexdigest()[:16]
    (root / ".venv" / ".somtorch-setup").write_text(f"{digest} {extras}\n")


def test_run_after_test_does_not_reinstall(checkout):
    _stamp(checkout, "test")
    for _ in range(3):  # the libusb check must not report the library missing, ever
        proc = _setup(checkout, "base")
        assert proc.returncode == 0, proc.stderr
        assert "installing" not in proc.stdout + proc.stderr


def test_test_after_run_installs_the_test_extra(checkout):
    _stamp(checkout, "base")
    before = (checkout / ".venv" / ".somtorch-setup").read_text()
    proc = _setup(checkout, "test")  # offline here: pip cannot fetch the build backend and fails
    assert "[setup] installing somtorch[test]" in proc.stdout
    assert proc.returncode != 0 and "failed" in proc.stderr
    assert (checkout / ".venv" / ".somtorch-setup").read_text() == before  # a failed install records nothing


def test_a_changed_pyproject_reinstalls(checkout):
    (checkout / ".venv" / ".somtorch-setup").write_text("0123456789abcdef test\n")
    proc = _setup(checkout, "base")
    assert "[setup] installing somtorch\n" in proc.stdout
