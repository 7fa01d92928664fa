"""Dependencies point one way: somtorch.synth may use somtorch.disparity, never the reverse."""

from __future__ import annotations

import re
from pathlib import Path

PKG = Path(__file__).resolve().parents[2] / "somtorch"


def test_core_and_disparity_never_import_synth():
    offenders = [str(p.relative_to(PKG)) for sub in ("core", "disparity") for p in (PKG / sub).rglob("*.py")
                 if re.search(r"\bsomtorch\.synth\b|from \.\.?synth\b", p.read_text(encoding="utf-8"))]
    assert offenders == []


def test_synth_imports_only_lower_layers():
    allowed = {"somtorch.synth", "somtorch.disparity", "somtorch.validation", "somtorch.atomic"}
    for p in (PKG / "synth").glob("*.py"):
        for mod in re.findall(r"^\s*(?:from|import) (somtorch[\w.]*)", p.read_text(encoding="utf-8"), re.M):
            assert any(mod == a or mod.startswith(a + ".") for a in allowed), f"{p.name} imports {mod}"
