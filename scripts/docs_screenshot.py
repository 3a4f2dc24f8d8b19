"""Render Markdown docs as a reader sees them on a forge, and screenshot them, to look at before a release.

    python scripts/docs_screenshot.py README.md docs/results.md --out /tmp/shots

Writes ``<out>/<name>.html`` (GitHub-like styling, tables and images resolved relative to the file) and
``<out>/<name>-<k>.png``: the page at 1,100 px wide cut into pieces of at most ``--piece`` px, so each can be viewed
whole. Needs a Chromium binary (``apt-get install chromium``; ``--chromium`` names another); nothing is fetched.
A tool for people checking the docs, not a test: the rendered-table tests are ``tests/test_summary.py``.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from markdown_it import MarkdownIt
from PIL import Image

CSS = """
body { font-family: -apple-system, 'DejaVu Sans', Helvetica, Arial, sans-serif; font-size: 15px; line-height: 1.5;
       color: #1f2328; max-width: 1012px; margin: 24px auto; padding: 0 32px; }
h1, h2 { border-bottom: 1px solid #d1d9e0; padding-bottom: .3em; }
code, pre { font-family: 'DejaVu Sans Mono', monospace; font-size: 85%; background: #f6f8fa; border-radius: 6px; }
code { padding: .2em .4em; } pre { padding: 16px; overflow: auto; } pre code { padding: 0; background: none; }
table { border-collapse: collapse; display: block; overflow: auto; margin: 16px 0; }
th, td { border: 1px solid #d1d9e0; padding: 6px 13px; } tr:nth-child(2n) { background: #f6f8fa; }
img { max-width: 100%; } a { color: #0969da; text-decoration: none; }
"""


def render_html(md_path: Path) -> str:
    """The Markdown file as one HTML page; relative links and images resolve against its folder."""
    body = MarkdownIt("commonmark", {"html": True}).enable("table").render(md_path.read_text(encoding="utf-8"))
    base = md_path.resolve().parent.as_uri() + "/"
    return f'<!doctype html><html><head><meta charset="utf-8"><base href="{base}"><style>{CSS}</style></head>' + (
        f"<body>{body}</body></html>"
    )


def screenshot(html: Path, png: Path, chromium: str, width: int = 1100, height: int = 40000) -> None:
    """A page taller than any doc, then cut to its last non-white row (Chromium headless has no full-page flag)."""
    with tempfile.TemporaryDirectory() as profile:
        subprocess.run(
            [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", f"--user-data-dir={profile}",
             f"--window-size={width},{height}", f"--screenshot={png}", html.as_uri()],
            check=True, capture_output=True, timeout=120,
        )  # fmt: skip
    img = Image.open(png).convert("RGB")
    rows = np.flatnonzero((np.asarray(img) < 250).any(axis=(1, 2)))
    img.crop((0, 0, width, int(rows[-1]) + 24 if len(rows) else 1)).save(png)


def pieces(png: Path, piece: int) -> list[Path]:
    """``png`` cut into pieces of at most ``piece`` px high, named ``<stem>-<k>.png``; the whole file is removed."""
    img = Image.open(png)
    out = []
    for k, top in enumerate(range(0, img.height, piece), start=1):
        p = png.with_name(f"{png.stem}-{k}.png")
        img.crop((0, top, img.width, min(img.height, top + piece))).save(p)
        out.append(p)
    png.unlink()
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("docs", nargs="+", type=Path, help="Markdown files")
    ap.add_argument("--out", type=Path, required=True, help="folder for the HTML and PNG files")
    ap.add_argument("--piece", type=int, default=2400, help="height of each PNG piece, px")
    ap.add_argument("--chromium", default=shutil.which("chromium") or shutil.which("chromium-browser"))
    a = ap.parse_args(argv)
    if not a.chromium:
        sys.exit("docs_screenshot: no Chromium found (apt-get install chromium, or --chromium PATH)")
    missing = [str(d) for d in a.docs if not d.is_file()]
    if missing:
        sys.exit(f"docs_screenshot: no such file: {', '.join(missing)}")
    a.out.mkdir(parents=True, exist_ok=True)
    for doc in a.docs:
        html = a.out / f"{doc.stem}.html"
        html.write_text(render_html(doc), encoding="utf-8")
        png = a.out / f"{doc.stem}.png"
        screenshot(html, png, a.chromium)
        print(doc, "->", ", ".join(str(p) for p in pieces(png, a.piece)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
