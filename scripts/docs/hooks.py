"""MkDocs hooks of the site (``mkdocs.yml``: ``hooks``).

One job: known link slips in pages that are being edited on other branches (which this branch must
not touch) are mended in the built page only, listed here one by one so that each stays visible; a
new broken link still fails the strict build. An entry whose text is gone is reported (INFO) so it
can be deleted.
"""

from __future__ import annotations

import logging
from typing import Any

log = logging.getLogger("mkdocs.hooks.somtorch")

# page -> [(link target as written, the target it means)]
MENDED_LINKS: dict[str, list[tuple[str, str]]] = {}


def on_page_markdown(markdown: str, *, page: Any, **kwargs: Any) -> str:
    """Mend the listed links of ``page`` (see :data:`MENDED_LINKS`)."""
    for written, meant in MENDED_LINKS.get(page.file.src_uri, []):
        if f"]({written})" in markdown:
            markdown = markdown.replace(f"]({written})", f"]({meant})")
        else:
            log.info("hooks.py: %s no longer links %s; delete its MENDED_LINKS entry", page.file.src_uri,
                     written)
    return markdown
