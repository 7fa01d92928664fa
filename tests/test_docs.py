"""The documentation site (``bash scripts/docs.sh``, ``mkdocs.yml``, ``scripts/docs/``).

Fast: every public name has a docstring; every key of every command's Hydra schema is in the
generated configuration reference. Slow: the site builds offline with zero warnings exactly as the
README says, every public name and notebook is in it; a broken cross-reference in a docstring stops
the build, naming the target and the file.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
pytest.importorskip("mkdocs_gen_files", reason="the docs extra (pip install -e '.[docs]') is not installed")


sys.path.insert(0, str(ROOT / "scripts" / "docs"))  # the site's generators (run by mkdocs-gen-files)
import docs_api  # noqa: E402
import docs_config  # noqa: E402

DEAD = "http://127.0.0.1:9"  # anything that reached for the network would fail
OFFLINE = {**os.environ, "HTTP_PROXY": DEAD, "HTTPS_PROXY": DEAD, "http_proxy": DEAD, "https_proxy": DEAD,
           "NO_PROXY": "", "no_proxy": "", "PIP_NO_INDEX": "1"}


def test_every_public_name_has_a_docstring():
    missing = docs_api.undocumented()
    assert not missing, "public names without a docstring (name, file:line):\n" + "\n".join(missing)


def test_the_docstring_check_names_what_it_misses(tmp_path, monkeypatch):
    pkg_dir = tmp_path / "tinypkg"
    pkg_dir.mkdir()
    (pkg_dir / "__init__.py").write_text('"""A package."""\n\n__all__ = ["fine", "bare"]\n\n\n'
                                         'def fine():\n    """Documented."""\n\n\ndef bare():\n    pass\n')
    import griffe

    pkg = griffe.load("tinypkg", search_paths=[str(tmp_path)], docstring_parser="google")
    monkeypatch.setattr(docs_api, "ROOT", tmp_path)
    assert docs_api.undocumented(pkg) == ["tinypkg.bare (tinypkg/__init__.py:10)"]


def test_every_config_key_is_in_the_reference():
    page = docs_config.config_page()
    keys = docs_config.config_keys()
    assert len(keys["run"]) > 100 and keys["synth"]
    missing = sorted({f"{cmd}: {k}" for cmd, ks in keys.items() for k in ks if f"`{k}`" not in page})
    assert not missing, "config keys missing from reference/config.md:\n" + "\n".join(missing)


def test_the_reference_lists_every_config_group_and_option():
    from experiments.cli import config_groups

    page = docs_config.config_page()
    for group, options in config_groups().items():
        assert f"### `{group}`" in page
        for option in options:
            assert f"`{group}={option}`" in page


@pytest.mark.slow
def test_the_site_builds_offline_with_zero_warnings(tmp_path):
    site = tmp_path / "site"
    proc = subprocess.run(["bash", "scripts/docs.sh", "--site-dir", str(site)], cwd=ROOT, capture_output=True,
                          text=True, timeout=900, env=OFFLINE)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-4000:]
    assert not re.search(r"^(WARNING|ERROR)", out, re.M), out[-4000:]
    html = {p.relative_to(site).as_posix(): p.read_text(errors="replace") for p in site.rglob("*.html")}
    # every public name has its anchor on its module's page (mkdocstrings: id = the dotted path)
    api = docs_api.public_api()
    for module, names in api.items():
        page = html[f"reference/{module}.html"]
        assert f'id="{module}"' in page, module
        for name in names:
            target = name.target
            home = html.get(f"reference/{target.module.path}.html", "") + page
            assert f'id="{target.path}"' in home, f"{name.path} ({name.where}) is not in the reference"
    # the configuration reference, the notebooks with their stored outputs, the pictures
    config = html["reference/config.html"]
    keys = {k for ks in docs_config.config_keys().values() for k in ks}
    missing = sorted(k for k in keys if f"<code>{k}</code>" not in config)
    assert not missing, missing
    for nb in (ROOT / "notebooks").glob("*.ipynb"):
        page = html[f"notebooks/{nb.stem}.html"]
        assert "jp-OutputArea" in page or "output_area" in page, nb.name
    pictures = html["pictures.html"]
    for png in (ROOT / "docs" / "gallery").glob("*.png"):
        assert f"gallery/{png.name}" in pictures and (site / "gallery" / png.name).is_file(), png.name
    # the guides and the four documents are pages of the site
    guides = [f"guides/{p.stem}.html" for p in (ROOT / "docs" / "guides").glob("*.md")]
    for page in ("index.html", *guides, "validation.html", "validation_log.html", "method.html", "results.html",
                 "tuned_constants.html", "scaling.html", "reliability.html", "synth.html", "log.html"):
        assert page in html, page
    # the validation page leads with today's figures; the sessions' record is a page of its own
    assert "Today&rsquo;s figures" in html["validation.html"] or "Today's figures" in html["validation.html"]
    assert 'id="session-41-issue-31' in html["validation_log.html"]
    assert 'id="session-41-issue-31' not in html["validation.html"]


@pytest.mark.slow
def test_a_broken_cross_reference_stops_the_build_naming_it(tmp_path):
    """A copy of the package with one docstring pointing at a name that does not exist, rendered
    with the site's own griffe extension and strict mode: the build fails and says where."""
    src = tmp_path / "src"
    shutil.copytree(ROOT / "somtorch", src / "somtorch", ignore=shutil.ignore_patterns("__pycache__"))
    tiles = src / "somtorch" / "tiles.py"
    text = tiles.read_text()
    assert ":func:`~somtorch.pipeline.run_pipeline`" in text
    tiles.write_text(text.replace("pipeline.run_pipeline`", "pipeline.run_pipelin`", 1))
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "index.md").write_text("# tiles\n\n::: somtorch.tiles\n")
    (tmp_path / "mkdocs.yml").write_text(f"""site_name: t
strict: true
plugins:
  - mkdocstrings:
      handlers:
        python:
          paths: [{src}]
          options:
            docstring_style: google
            extensions: ["{ROOT / 'scripts' / 'docs' / 'griffe_roles.py'}:SphinxRoles"]
            scoped_crossrefs: true
""")
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=600,
                          env={**OFFLINE, "DISABLE_MKDOCS_2_WARNING": "true", "NO_MKDOCS_2_WARNING": "1"})
    out = proc.stdout + proc.stderr
    assert proc.returncode != 0, out[-3000:]
    line = next((ln for ln in out.splitlines() if "run_pipelin'" in ln), "")
    assert "somtorch.pipeline.run_pipelin" in line and "somtorch/tiles.py" in line, out[-3000:]
