"""Shared pytest fixtures."""

from __future__ import annotations

from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``<repo root>/../shared/data`` (the real sample data); skips the test when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"../shared/data not found: {SHARED_DATA} does not exist (the real sample data sits "
                    "next to the repository checkout); tests that read it are skipped")
    return SHARED_DATA


# The fast subset (pytest -m "not slow", README): end-to-end suites that start processes, run
# experiments or whole studies, and the quality gates, are "slow" as a group; other slow tests
# carry @pytest.mark.slow themselves.
_SLOW_PARTS = ("experiments", "quality", "fuzz")
_SLOW_FILES = ("test_notebooks.py", "test_benchmarks.py", "test_distributed.py", "test_hostile_files.py")


@pytest.fixture
def kernel(monkeypatch):
    """The native kernels (``somtorch.core.native``) enabled, even when the suite runs with
    ``SOMTORCH_NATIVE=0``; a skip with the reason where they cannot be built here (the callers'
    torch paths are tested anyway)."""
    from somtorch.core import native

    monkeypatch.delenv(native.ENV_SWITCH, raising=False)
    if native.library() is None:
        pytest.skip(f"the native kernel could not be built or loaded ({native._failed}); "
                    "its callers use their torch paths")


def pytest_collection_modifyitems(config, items):
    slow = pytest.mark.slow
    for item in items:
        parts = Path(str(item.fspath)).parts
        if any(p in parts for p in _SLOW_PARTS) or parts[-1] in _SLOW_FILES:
            item.add_marker(slow)
