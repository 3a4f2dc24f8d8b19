"""docs/extending.md's runnable examples run as written (smoke preset, a temporary results folder)."""

from __future__ import annotations

import re

import pandas as pd

from omcrl.runs import read_identity
from omcrl.scenes import SCENE_SPECS, generate_scene


def _runnable_blocks(text: str) -> list[str]:
    return re.findall(r"<!-- runnable: tests/test_extending.py -->\n```python\n(.*?)```", text, flags=re.S)


def test_your_own_course_trains_evaluates_and_tabulates(repo_root, tmp_path, capsys):
    blocks = _runnable_blocks((repo_root / "docs" / "extending.md").read_text(encoding="utf-8"))
    assert len(blocks) == 1
    code = blocks[0].replace('"results_dir=results"', f'"results_dir={tmp_path}"')
    assert code != blocks[0]
    ns: dict = {}
    try:
        exec(compile(code, "docs/extending.md", "exec"), ns)
        _check(ns)
    finally:
        SCENE_SPECS.pop("slalom-v0", None)  # the registry is global: leave it as the other tests expect


def _check(ns: dict) -> None:
    table, ppo = ns["table"], ns["ppo"]
    assert read_identity(ppo.run_dir)["identity"]["env"]["scene"] == "slalom-v0"  # in the run's identity
    sr = table["SR"]
    assert set(sr.index.get_level_values("scene")) == {"box-v0", "slalom-v0"}
    assert set(sr.index.get_level_values("method")) == {"ppo", "hybrid-apf"}
    assert sr.between(0, 100).all()
    # The course is a scene: its obstacles are the three walls, whatever the episode's seed.
    for seed in (0, 1):
        assert len(generate_scene("slalom-v0", seed, arena_half=8.0)) == 3
    assert isinstance(ns["episodes"], pd.DataFrame) and (ns["episodes"]["scene"] == "slalom-v0").any()
