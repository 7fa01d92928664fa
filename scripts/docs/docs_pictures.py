"""The pictures page (``pictures.md``): the summary figure with the README's caption, and every image
of ``docs/gallery/`` with the section of the page that shows it, or the script that draws it."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _headings(text: str) -> list[tuple[int, str]]:
    return [(m.start(), m.group(2)) for m in re.finditer(r"^(#{1,4}) (.+)$", text, re.M)]


def _slug(heading: str) -> str:
    from markdown.extensions.toc import slugify

    return slugify(re.sub(r"[`*]", "", heading), "-")


def pictures_page() -> str:
    """The summary figure (caption from the README) and every gallery image, each with the section
    of the page that shows it (and that section's legend), or the script that draws it."""
    readme = (ROOT / "README.md").read_text()
    m = re.search(r"!\[[^\]]*\]\(docs/img/(\S+?)\)\n\n\*(.+?)\*\n", readme, re.S)
    out = ["# Pictures", "", "Every picture the documentation shows, with its caption; generated from the "
           "files in `docs/img/` and `docs/gallery/` and the pages that embed them.", ""]
    out += ["## One run of the pipeline", ""]
    if m:
        out += [f"![summary of one run](img/{m.group(1)})", "", "*" + m.group(2).replace("\n", " ") + "*", ""]
    used: dict[str, tuple[str, str, str]] = {}
    notes: dict[str, str] = {}  # an image's own words where a page gives them: the rest of its table cell
    titles: dict[str, str] = {}  # page -> its title
    for page in sorted((ROOT / "docs").glob("*.md")):
        text = page.read_text()
        heads = _headings(text)
        titles[page.name] = re.sub(r"[`*]", "", heads[0][1]) if heads else page.stem
        for hit in re.finditer(r"\(gallery/([^)\s]+\.png)\)", text):
            before = [h for pos, h in heads if pos < hit.start()]
            head = before[-1] if before else page.stem
            pos = next(p for p, h in heads if h == head) if before else 0
            rest = text[pos:].split("\n\n")
            prose = len(rest) > 1 and not rest[1].lstrip().startswith(("|", "!", "`"))
            legend = rest[1].replace("\n", " ") if prose else ""
            used.setdefault(hit.group(1), (page.name, head, legend))
        for img in re.finditer(r"!\[[^\]]*\]\(gallery/([^)\s]+\.png)\)([^|\n]*)", text):
            if img.group(2).strip():
                notes.setdefault(img.group(1), img.group(2).strip())
    synth_doc = importlib.import_module("experiments.synth_gallery").__doc__ or ""
    synth_legend = synth_doc.split("\n\n")[1].replace("\n", " ") if "\n\n" in synth_doc else ""
    groups: dict[tuple[str, str, str], list[str]] = {}
    for png in sorted((ROOT / "docs" / "gallery").glob("*.png")):
        if png.name in used:
            key = used[png.name]
        elif png.name.startswith("synth_"):
            key = ("synth.md", "The generator's families (`python -m experiments.synth_gallery`)",
                   synth_legend)
        else:
            key = ("", "Other pictures", "")
        groups.setdefault(key, []).append(png.name)
    for (page, head, legend), names in groups.items():
        out += [f"## {re.sub(r'[`]', '', head)}", ""]
        if page:
            anchor = "" if head.startswith("The generator") else f"#{_slug(head)}"
            out += [f"From [{titles.get(page, page)}]({page}{anchor}). {legend}".strip(), ""]
        for name in names:
            note = f" — {notes[name]}" if name in notes else ""
            out += [f"![{Path(name).stem}](gallery/{name})", "", f"*`{Path(name).stem}`*{note}", ""]
    return "\n".join(out)


