"""MkDocs hooks (mkdocs.yml `hooks:`): the site serves results/ and CHANGELOG.md from where they live in the
checkout, without copies or symlinks.

- on_files: every file under results/ joins the site at `results/...` (its READMEs and tables as pages, figures
  and JSON as files), so the docs' links and images into results/ resolve.
- on_page_markdown: a docs page links to `../results/...` (right on GitHub, where docs/ is a folder beside
  results/); on the site results/ sits beside the pages, so the `../` is dropped. A line
  `<!-- include: PATH -->` is replaced by the file at PATH (relative to the checkout), its first heading dropped
  and its relative links rewritten to stay right from the including page.
"""

from __future__ import annotations

import posixpath
import re
from pathlib import Path

from mkdocs.structure.files import File

ROOT = Path(__file__).resolve().parent.parent
INCLUDE = re.compile(r"^<!-- include: (\S+) -->$", re.MULTILINE)
LINK = re.compile(r"(\]\()([^)\s]+)(\))")


def on_files(files, config):
    for path in sorted((ROOT / "results").rglob("*")):
        if path.is_file():
            files.append(File(path.relative_to(ROOT).as_posix(), src_dir=str(ROOT), dest_dir=config["site_dir"],
                              use_directory_urls=config["use_directory_urls"]))
    return files


def _relative(target: str) -> bool:
    return not (target.startswith(("#", "/")) or re.match(r"^[a-z][a-z0-9+.-]*:", target))


def _rebase(markdown: str, folder: str) -> str:
    """Links of a file in `folder` (relative to the checkout) as seen from a page at the docs root."""
    def one(m: re.Match) -> str:
        target = m.group(2)
        if not _relative(target) or not folder:
            return m.group(0)
        return m.group(1) + posixpath.normpath(posixpath.join(folder, target)) + m.group(3)
    return LINK.sub(one, markdown)


def _include(m: re.Match) -> str:
    rel = m.group(1)
    text = (ROOT / rel).read_text()
    text = re.sub(r"\A#[^\n]*\n+", "", text)  # the page has its own title
    return _rebase(text, posixpath.dirname(rel))


def on_page_markdown(markdown, page, config, files):
    if page.file.src_uri.startswith("results/"):
        return markdown
    markdown = INCLUDE.sub(_include, markdown)
    return markdown.replace("](../results/", "](results/")
