"""The words of the generated pages: Jinja2 templates (``omcrl/pipeline/templates/*.md.j2``) filled with data.

A block of the README or of docs/results.md is computed in the library (:mod:`omcrl.pipeline.glance`,
:mod:`omcrl.pipeline.summary`, :mod:`omcrl.pipeline.why`) and worded in a template, so its sentences can be
edited without reading code. :func:`render` fills a template and lays out its Markdown: a paragraph may be
written over several lines in the template (it is joined into one, then wrapped at 120 characters as every
generated page is, :func:`wrap`); table rows, headings, images and blank lines are kept as they are; a list item
(``- ``) continues on lines indented under it; a line ending in a backslash ends its paragraph's line there (the
backslash dropped), for two lines of prose with no blank line between them.
"""

from __future__ import annotations

import textwrap
from functools import cache
from pathlib import Path
from typing import Any

TEMPLATES = Path(__file__).with_name("templates")


@cache
def _environment() -> Any:
    import jinja2

    # StrictUndefined: a name the code does not pass is an error, not an empty string in a published page.
    return jinja2.Environment(
        loader=jinja2.FileSystemLoader(TEMPLATES),
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=False,
        autoescape=False,
    )


def wrap(line: str, width: int = 120) -> str:
    """A prose line or list item wrapped at ``width`` (Markdown renders it the same); table rows as they are."""
    if line.startswith("|") or len(line) <= width:
        return line
    indent = "  " if line.startswith("- ") else ""
    return textwrap.fill(line, width, subsequent_indent=indent, break_long_words=False, break_on_hyphens=False)


def _kept(line: str) -> bool:
    """A line that is not prose to join: blank, a table row, a heading, an image, a fence or a marker."""
    s = line.strip()
    return not s or s.startswith(("|", "#", "![", "```", "<!--"))


def reflow(text: str) -> list[str]:
    """The logical lines of Markdown written over several lines: each paragraph and each list item on one line."""
    out: list[str] = []
    joining = False  # the previous line is prose that the next prose line continues
    for line in text.splitlines():
        ends = line.endswith("\\")
        line = line[:-1] if ends else line
        if _kept(line):
            out.append(line.rstrip())
            joining = False
            continue
        if joining and (not line.startswith("- ") or line.startswith("  ")):
            out[-1] = f"{out[-1]} {line.strip()}"
        else:
            out.append(line.rstrip())
        joining = not ends
    return out


def render(template: str, *, layout: bool = True, **data: Any) -> str:
    """Fill ``templates/<template>`` with ``data`` and lay it out (:func:`reflow`, then :func:`wrap` per line);
    ``layout=False``: as the template writes it (a page whose lines are not wrapped, results/<preset>/summary.md)."""
    text = _environment().get_template(template).render(**data)
    return "\n".join(wrap(x) for x in reflow(text)) if layout else text
