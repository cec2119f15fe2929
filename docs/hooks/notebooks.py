"""mkdocs hook: show the repository's notebooks (``notebooks/*.ipynb``) on the site.

The notebooks live in ``notebooks/`` at the repository root, where the test suite executes
them. mkdocs only renders files inside ``docs/``, so this hook adds each notebook to the site as
``notebooks/<name>.ipynb`` (a file read from ``notebooks/`` itself: no copy, no symlink), before
mkdocs-jupyter turns it into a page; it is rendered as stored, without executing it. The page
``notebooks.md`` gets the list of them, with each notebook's first heading as its title, in
place of the line ``<!-- notebooks -->``, and the nav's entry for that page becomes a section
holding it and the notebooks.
"""

from __future__ import annotations

import json
from pathlib import Path

from mkdocs.plugins import event_priority
from mkdocs.structure.files import File, Files

NOTEBOOKS = "notebooks"
MARKER = "<!-- notebooks -->"


def _notebooks(config) -> list[Path]:
    root = Path(config["config_file_path"]).resolve().parent
    return sorted((root / NOTEBOOKS).glob("*.ipynb"))


def _title(path: Path) -> str:
    """The notebook's first Markdown heading, else its file name."""
    try:
        cells = json.loads(path.read_text(encoding="utf-8")).get("cells", [])
    except (OSError, ValueError):
        return path.stem
    for c in cells:
        if c.get("cell_type") != "markdown":
            continue
        for line in "".join(c.get("source", [])).splitlines():
            if line.startswith("#"):
                return line.lstrip("#").strip()
    return path.stem


def on_config(config):
    """The nav's ``notebooks.md`` entry becomes a section: that page, then every notebook."""
    found = [f"{NOTEBOOKS}/{p.name}" for p in _notebooks(config)]
    nav = config.get("nav")
    if not nav or not found:
        return config
    for i, item in enumerate(nav):
        if isinstance(item, dict) and list(item.values()) == [f"{NOTEBOOKS}.md"]:
            (title,) = item
            nav[i] = {title: [f"{NOTEBOOKS}.md", *found]}
    return config


@event_priority(100)  # before mkdocs-jupyter's on_files, which turns .ipynb files into pages
def on_files(files: Files, config) -> Files:
    root = Path(config["config_file_path"]).resolve().parent
    for path in _notebooks(config):
        uri = f"{NOTEBOOKS}/{path.name}"
        if files.get_file_from_path(uri) is None:
            # a file whose source folder is the repository's root: its page is
            # notebooks/<name>/ as if it were docs/notebooks/<name>.ipynb
            files.append(
                File(
                    uri,
                    src_dir=str(root),
                    dest_dir=config["site_dir"],
                    use_directory_urls=config["use_directory_urls"],
                )
            )
    return files


def on_page_markdown(markdown: str, page, config, files) -> str:
    if MARKER not in markdown:
        return markdown
    items = [f"- [{_title(p)}]({NOTEBOOKS}/{p.name})" for p in _notebooks(config)]
    return markdown.replace(MARKER, "\n".join(items) or "*(no notebook in `notebooks/` yet)*")
