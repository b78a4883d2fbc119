"""Build hooks: pages generated from files that live elsewhere in the repository.

- the example notebooks (``notebooks/``) are rendered, executed at build time in
  small mode (``DIFFIMPACT_NOTEBOOK_SMALL=1``: few points, few iterations);
- the Performance page is ``benchmarks/RESULTS.md`` itself, with its plots, so
  no measured number is typed twice;
- the Changelog page is ``CHANGELOG.md``;
- equation tags written in docstrings and pages, e.g. ``(JG-5)``, link to the
  anchor the Physics pages give that tag (``{#JG-5}``), so docstrings stay
  plain text for ``help()`` and still link in the site.
"""

import os
import pathlib
import re
import tempfile

from mkdocs.plugins import event_priority
from mkdocs.structure.files import File
from mkdocs.utils import get_relative_url

ROOT = pathlib.Path(__file__).resolve().parent.parent
GENERATED = {
    "performance.md": ROOT / "benchmarks" / "RESULTS.md",
    "changelog.md": ROOT / "CHANGELOG.md",
}


def on_config(config):
    # the notebooks read these; a reader's own settings win
    os.environ.setdefault("DIFFIMPACT_NOTEBOOK_SMALL", "1")
    os.environ.setdefault("DIFFIMPACT_NOTEBOOK_OUT", tempfile.mkdtemp(prefix="nb-"))
    return config


@event_priority(100)  # before mkdocs-jupyter, which converts the notebooks
def on_files(files, config):
    for path in sorted((ROOT / "notebooks").glob("*.ipynb")):
        files.append(
            File(
                f"notebooks/{path.name}",
                src_dir=str(ROOT),
                dest_dir=config["site_dir"],
                use_directory_urls=config["use_directory_urls"],
            )
        )
    for name, source in GENERATED.items():
        files.append(File.generated(config, name, content=source.read_text()))
    for png in sorted((ROOT / "benchmarks").glob("*.png")):
        # RESULTS.md links its plots by bare name; the page sits at the root
        files.append(File.generated(config, png.name, abs_src_path=str(png)))
    return files


# an equation tag of one of the Physics pages' families (JG-5, JG05-6, F-2,
# COR-1, ...); only tags that a Physics page defines are linked
TAG = re.compile(r"\b((?:JG05|JG|COR|CA|IM|G|H|F|R|S|M|Q)-\d+)\b")
ANCHOR = re.compile(r"\{#([A-Za-z0-9-]+)\}")
_anchors = {}


def physics_anchors():
    """``tag -> page path`` of every explicit anchor on the Physics pages."""
    out = {}
    for page in sorted((ROOT / "docs" / "physics").glob("*.md")):
        for tag in ANCHOR.findall(page.read_text()):
            out[tag] = f"physics/{page.name}"
    return out


def on_pre_build(config):
    _anchors.clear()
    _anchors.update(physics_anchors())


PLOT_LINK = re.compile(r"\[`([\w.-]+\.png)`\]\(\1\)")


def on_page_markdown(markdown, page, config, files):
    # RESULTS.md links its plots (for a reader on GitHub); the Performance
    # page shows them
    if page.file.src_uri != "performance.md":
        return markdown
    paragraphs = markdown.split("\n\n")
    for i, text in enumerate(paragraphs):
        plots = PLOT_LINK.findall(text)
        if plots and not text.lstrip().startswith("|"):  # not inside a table
            paragraphs[i] = text + "".join(f"\n\n![{p}]({p})" for p in plots)
    return "\n\n".join(paragraphs)


def on_page_content(html, page, config, files):
    if page.file.src_uri.startswith("physics/") or not _anchors:
        return html
    pieces = re.split(r"(<[^>]+>)", html)
    in_link = 0
    for i, piece in enumerate(pieces):
        if piece.startswith("<"):
            if re.match(r"<a[\s>]", piece):
                in_link += 1
            elif piece.startswith("</a"):
                in_link = max(0, in_link - 1)
            continue
        if in_link:
            continue

        def link(m):
            tag = m.group(1)
            target = _anchors.get(tag)
            if target is None:
                return tag
            url = files.get_file_from_path(target).url
            href = get_relative_url(url, page.url) + "#" + tag
            return f'<a href="{href}">{tag}</a>'

        pieces[i] = TAG.sub(link, piece)
    return "".join(pieces)
