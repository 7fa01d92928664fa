"""The generated pages of the documentation site, written at every ``mkdocs build``.

Run by mkdocs-gen-files (``mkdocs.yml``); nothing it writes is committed:

* ``reference/`` — one page per public module of ``somtorch`` (rendered by mkdocstrings from the
  docstrings), package pages listing their public names, and ``reference/SUMMARY.md``, the section's
  navigation (mkdocs-literate-nav): :mod:`docs_api`;
* ``reference/config.md`` — every config group, option and key: :mod:`docs_config`;
* ``pictures.md`` — the summary figure and the gallery with captions: :mod:`docs_pictures`;
* ``notebooks/*.ipynb`` — the stored notebooks (mkdocs-jupyter renders their stored outputs).
"""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

import docs_api  # noqa: E402
import docs_config  # noqa: E402
import docs_pictures  # noqa: E402

ROOT = docs_api.ROOT


def write_all() -> None:
    """Write every generated page into the build (mkdocs-gen-files' virtual files). A public name
    without a docstring, or a config key the configuration reference does not name, is a warning,
    so the strict build stops with the name and the file."""
    import logging

    import mkdocs_gen_files

    log = logging.getLogger("mkdocs.plugins.somtorch_docs")
    for missing in docs_api.undocumented():
        log.warning("gen_pages.py: public name without a docstring: %s", missing)
    config = docs_config.config_page()
    for command, keys in docs_config.config_keys().items():
        for key in keys:
            if f"`{key}`" not in config:
                log.warning("gen_pages.py: config key %s of %s is missing from reference/config.md", key,
                            docs_config.COMMANDS[command])
    for page, text in docs_api.api_pages().items():
        with mkdocs_gen_files.open(f"reference/{page}", "w") as f:
            f.write(text)
    with mkdocs_gen_files.open("reference/config.md", "w") as f:
        f.write(config)
    with mkdocs_gen_files.open("pictures.md", "w") as f:
        f.write(docs_pictures.pictures_page())
    for nb in sorted((ROOT / "notebooks").glob("*.ipynb")):
        with mkdocs_gen_files.open(f"notebooks/{nb.name}", "wb") as f:
            f.write(nb.read_bytes())


if __name__ in ("__main__", "<run_path>"):
    write_all()
