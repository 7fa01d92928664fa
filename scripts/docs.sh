#!/usr/bin/env bash
# Build the documentation site into site/ (open site/index.html): offline, strict (a warning is an
# error: a broken link or cross-reference, a docstring the reference cannot read). Installs the docs
# extra into .venv first when its tools are missing (scripts/setup.sh; idempotent). Extra arguments
# go to `mkdocs build`, e.g. bash scripts/docs.sh --site-dir /tmp/site
set -euo pipefail
cd "$(dirname "$0")/.."
if ! .venv/bin/python -c 'import mkdocs, material, mkdocstrings_handlers.python, mkdocs_gen_files, mkdocs_literate_nav, mkdocs_jupyter' 2>/dev/null; then
  bash scripts/setup.sh docs
fi
# the site needs no network: no web fonts, no downloads, notebooks rendered from their stored outputs;
# a banner about MkDocs 2 that a plugin prints on every build is noise here (mkdocs is pinned < 2)
export DISABLE_MKDOCS_2_WARNING=true NO_MKDOCS_2_WARNING=1
exec .venv/bin/python -m mkdocs build --strict --clean "$@"
