"""Packaging: pyproject.toml and environment.yml pin the same versions; the entry points are wired up."""

from __future__ import annotations

import os
import re
import subprocess
import tomllib
from pathlib import Path

import pytest
import yaml


def normalise(name: str) -> str:
    """PEP 503 name normalisation: case-insensitive, runs of '-', '_', '.' are equal."""
    return re.sub(r"[-_.]+", "-", name).lower()


def parse_pins(specs: list[str], where: str) -> dict[str, str]:
    """``["torch==2.13.0", ...]`` -> ``{"torch": "2.13.0"}``; every entry must be an exact ``==`` pin."""
    pins: dict[str, str] = {}
    for spec in specs:
        m = re.fullmatch(r"\s*([A-Za-z0-9][A-Za-z0-9._-]*)\s*==\s*([^\s;,]+)\s*", spec)
        assert m, f"{where}: {spec!r} is not an exact 'name==version' pin"
        name = normalise(m.group(1))
        assert name not in pins, f"{where}: {m.group(1)} is listed twice"
        pins[name] = m.group(2)
    return pins


def pyproject_pins(root: Path) -> dict[str, str]:
    data = tomllib.loads((root / "pyproject.toml").read_text())
    # environment.yml installs every extra (deploy, lab, dev), so every extra's pins must agree with it.
    specs = list(data["project"]["dependencies"])
    for extra in data["project"]["optional-dependencies"].values():
        specs += [s for s in extra if s not in specs]
    return parse_pins(specs, "pyproject.toml")


def environment_pins(root: Path) -> tuple[dict[str, str], dict]:
    env = yaml.safe_load((root / "environment.yml").read_text())
    pip = [d for d in env["dependencies"] if isinstance(d, dict) and "pip" in d]
    assert len(pip) == 1, "environment.yml: expected one 'pip:' section"
    specs = [s for s in pip[0]["pip"] if s.strip() not in ("-e .", "-e ./", "--editable .")]
    assert len(specs) == len(pip[0]["pip"]) - 1, "environment.yml: the pip section must install the kit with '-e .'"
    return parse_pins(specs, "environment.yml"), env


def pin_differences(a: dict[str, str], b: dict[str, str]) -> list[str]:
    """Human-readable differences between two pin sets (empty when they agree exactly)."""
    out = [f"{n}: only in pyproject.toml ({a[n]})" for n in sorted(set(a) - set(b))]
    out += [f"{n}: only in environment.yml ({b[n]})" for n in sorted(set(b) - set(a))]
    out += [f"{n}: pyproject.toml {a[n]} != environment.yml {b[n]}" for n in sorted(set(a) & set(b)) if a[n] != b[n]]
    return out


def test_pins_agree(repo_root):
    a = pyproject_pins(repo_root)
    b, _ = environment_pins(repo_root)
    assert "torch" in a
    assert pin_differences(a, b) == []


def test_pin_check_detects_a_difference(repo_root):
    a = pyproject_pins(repo_root)
    b, _ = environment_pins(repo_root)
    changed = dict(b, torch="9.9.9")
    assert pin_differences(a, changed) == ["torch: pyproject.toml 2.13.0 != environment.yml 9.9.9"]
    missing = {k: v for k, v in b.items() if k != "ruff"}
    assert pin_differences(a, missing) == [f"ruff: only in pyproject.toml ({a['ruff']})"]
    assert pin_differences(a, dict(b, extra="1.0")) == ["extra: only in environment.yml (1.0)"]


def test_names_are_normalised():
    assert parse_pins(["PyYAML==6.0.3", "opencv_python.Headless==1"], "x") == {
        "pyyaml": "6.0.3",
        "opencv-python-headless": "1",
    }
    with pytest.raises(AssertionError, match="exact"):
        parse_pins(["numpy>=2"], "x")


def test_environment_yml_shape(repo_root):
    _, env = environment_pins(repo_root)
    assert env["name"] == "omcrl"
    assert env["channels"] == ["conda-forge"]
    plain = [d for d in env["dependencies"] if isinstance(d, str)]
    assert "python=3.11" in plain and "pip" in plain
    requires = tomllib.loads((repo_root / "pyproject.toml").read_text())["project"]["requires-python"]
    assert requires == ">=3.11"


def test_readme_starts_with_the_two_commands(repo_root):
    head = "\n".join((repo_root / "README.md").read_text().splitlines()[:15])
    assert "./reproduce.sh --quick" in head
    assert "./reproduce.sh --test" in head


def test_ci_runs_the_readme_test_command(repo_root):
    ci = repo_root / ".ci" / "run"
    text = ci.read_text()
    assert text.startswith("#!/usr/bin/env bash")
    assert "set -euo pipefail" in text
    assert "./reproduce.sh --test" in text
    assert os.access(ci, os.X_OK), ".ci/run must be executable"


def test_reproduce_script(repo_root):
    script = repo_root / "reproduce.sh"
    assert os.access(script, os.X_OK), "reproduce.sh must be executable"
    assert "set -euo pipefail" in script.read_text()
    assert subprocess.run(["bash", "-n", str(script)], capture_output=True).returncode == 0
    # --help and a bad mode must answer before touching .venv.
    r = subprocess.run(["bash", str(script), "--help"], capture_output=True, text=True, timeout=30)
    assert r.returncode == 0
    for mode in ("--test", "--smoke", "--quick", "--paper"):
        assert mode in r.stdout
    r = subprocess.run(["bash", str(script), "--nonsense"], capture_output=True, text=True, timeout=30)
    assert r.returncode == 2 and "unknown mode" in r.stderr


def test_presets_ship_with_the_package():
    from importlib.resources import files

    for name in ("smoke", "quick", "paper"):
        assert (files("omcrl") / "presets" / f"{name}.yaml").is_file()


def test_docs_and_readmes_exist(repo_root):
    for rel in ("docs/DEVIATIONS.md", "data/README.md", "results/README.md", "environment.yml"):
        assert (repo_root / rel).is_file(), rel


def _anchors(page) -> set[str]:
    """The anchors GitHub gives the headings of a Markdown page: the heading's text (links and code marks
    dropped) lower-cased, every character that is not a letter, digit, ``_``, ``-`` or space removed, spaces
    made hyphens; a repeated heading gets ``-1``, ``-2``, ..."""
    import re

    out, seen, fence = set(), {}, False
    for line in page.read_text().splitlines():
        if line.startswith("```"):
            fence = not fence
        m = None if fence else re.match(r"#{1,6}\s+(.*?)\s*#*\s*$", line)
        if m is None:
            continue
        text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", m.group(1)).replace("`", "").replace("*", "")
        slug = re.sub(r"[^\w\- ]", "", text.strip().lower()).replace(" ", "-")
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        out.add(slug if n == 0 else f"{slug}-{n}")
    return out


def test_every_relative_link_in_the_docs_resolves(repo_root):
    """Links between the README, docs/ (the lab notes in docs/history/ too) and the repository's files
    (``[text](path)``, ``[text](path#anchor)`` and ``[text](#anchor)``) point at files that exist, and an anchor into a
    Markdown page at one of its headings; web links are not followed."""
    import re

    pages = [repo_root / "README.md", *sorted((repo_root / "docs").rglob("*.md"))]
    checked, anchored, broken = 0, 0, []
    for page in pages:
        for target in re.findall(r"\]\(([^)\s]+)\)", page.read_text()):
            if re.match(r"[a-z]+:", target):
                continue
            file, _, anchor = target.partition("#")
            path = (page.parent / file).resolve() if file else page
            checked += 1
            if not path.exists():
                broken.append(f"{page.relative_to(repo_root)} -> {target}")
            elif anchor and path.suffix == ".md":
                anchored += 1
                if anchor not in _anchors(path):
                    broken.append(f"{page.relative_to(repo_root)} -> {target} (no such heading)")
    assert checked >= 15 and anchored >= 10 and broken == [], broken


def test_user_docs_keep_lines_within_120_characters(repo_root):
    """The README and the user pages of docs/ (not the lab notes in docs/history/) wrap prose at 120 characters.
    Table rows are exempt (a Markdown row cannot wrap), and so is a line that is one unbreakable token (a long link)."""
    pages = [repo_root / "README.md", *sorted((repo_root / "docs").glob("*.md"))]
    long = [
        f"{page.relative_to(repo_root)}:{i} ({len(line)} characters)"
        for page in pages
        for i, line in enumerate(page.read_text(encoding="utf-8").splitlines(), 1)
        if len(line) > 120 and not line.lstrip().startswith("|") and " " in line.strip()
    ]
    assert len(pages) >= 10 and long == [], long
