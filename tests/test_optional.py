"""Tests of somtorch._optional: real imports, real loader errors, stand-in packages on sys.path."""

from __future__ import annotations

import ctypes
import importlib
import sys

import pytest

from somtorch._optional import import_error_message, import_open3d, optional_import

LIBUSB_TEXT = "libusb-1.0.so.0: cannot open shared object file: No such file or directory"


def _package(tmp_path, monkeypatch, name: str, body: str) -> str:
    """Put a package ``name`` whose ``__init__`` runs ``body`` on sys.path; return its name."""
    (tmp_path / name).mkdir()
    (tmp_path / name / "__init__.py").write_text(body)
    monkeypatch.syspath_prepend(str(tmp_path))
    importlib.invalidate_caches()
    monkeypatch.delitem(sys.modules, name, raising=False)
    return name


def test_import_open3d_returns_the_module():
    o3d = import_open3d()
    assert o3d is sys.modules["open3d"]
    assert hasattr(o3d.geometry, "PointCloud")


def test_optional_import_returns_an_installed_module():
    import json

    assert optional_import("json") is json
    assert optional_import("os.path").join("a", "b") == "a/b"


def test_missing_module_names_the_pip_package():
    with pytest.raises(ImportError, match=r"pip install somtorch-no-such-dist") as info:
        optional_import("somtorch_no_such_module_xyz", pip_name="somtorch-no-such-dist")
    assert "somtorch_no_such_module_xyz is not installed" in str(info.value)
    assert isinstance(info.value.__cause__, ModuleNotFoundError)
    assert info.value.name == "somtorch_no_such_module_xyz"


def test_missing_libusb_says_which_apt_package(tmp_path, monkeypatch):
    name = _package(tmp_path, monkeypatch, "somtorch_fake_usb_dep", f"raise ImportError({LIBUSB_TEXT!r})\n")
    with pytest.raises(ImportError) as info:
        optional_import(name, pip_name="fake-usb-dep", hint="Needed for tests.")
    msg = str(info.value)
    assert "system library libusb-1.0.so.0 is missing" in msg
    assert "apt-get update && apt-get install -y libusb-1.0-0" in msg
    assert msg.endswith("Needed for tests.")
    assert str(info.value.__cause__) == LIBUSB_TEXT and "\n" not in msg  # one paragraph, original chained


def test_message_for_the_open3d_libusb_failure():
    msg = import_error_message("open3d", "open3d", ImportError(LIBUSB_TEXT))
    assert msg.startswith("open3d is installed but cannot be loaded")
    assert "apt-get update && apt-get install -y libusb-1.0-0" in msg and "pip install" not in msg


def test_a_real_loader_error_for_an_unknown_library(tmp_path, monkeypatch):
    # ctypes raises OSError with the dynamic loader's own wording
    lib = "libsomtorch-absent-test.so.7"
    with pytest.raises(OSError, match="cannot open shared object file"):
        ctypes.CDLL(lib)
    body = f"import ctypes\nctypes.CDLL({lib!r})\n"
    name = _package(tmp_path, monkeypatch, "somtorch_fake_ctypes_dep", body)
    with pytest.raises(ImportError, match=f"system library {lib} is missing") as info:
        optional_import(name)
    assert f"apt-file search {lib}" in str(info.value)
    assert isinstance(info.value.__cause__, OSError)


def test_a_missing_python_dependency_is_not_reported_as_the_module_itself(tmp_path, monkeypatch):
    name = _package(tmp_path, monkeypatch, "somtorch_fake_pkg", "import somtorch_missing_dep_xyz\n")
    with pytest.raises(ImportError, match="dependency 'somtorch_missing_dep_xyz' is missing") as info:
        optional_import(name, pip_name="fake-pkg")
    assert "pip install --force-reinstall fake-pkg" in str(info.value)


def test_other_import_errors_suggest_a_reinstall(tmp_path, monkeypatch):
    name = _package(tmp_path, monkeypatch, "somtorch_fake_broken", "from os import no_such_name\n")
    with pytest.raises(ImportError, match=r"could not be imported \(ImportError: cannot import name") as info:
        optional_import(name, pip_name="fake-broken")
    assert "pip install --force-reinstall fake-broken" in str(info.value)
