"""What each stage reports: one record type per stage, written to ``results/<preset>/tables/<name>.json``.

The notebooks build these records from what their stage did and :meth:`StageRecord.write` them; the summary
(:mod:`omcrl.pipeline.summary`) :meth:`StageRecord.read` s them; tests build them to fake a stage. So the keys
live here once, not in seven notebooks, the summary and the tests. The JSON layout is the one the notebooks
wrote before these types existed, so results written then are still read.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

from omcrl.runs import CorruptFile
from omcrl.utils.io import atomic_write_text


@dataclass
class StageRecord:
    """Base of the stage records: JSON in ``tables/<FILE>``."""

    FILE: ClassVar[str] = ""

    def to_json(self) -> dict[str, Any]:
        """The record as the JSON object in its file."""
        return dataclasses.asdict(self)

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> StageRecord:
        """The record of a JSON object: fields it lacks take their defaults (files of older versions), keys this
        version does not know are ignored."""
        names = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in names})

    def write(self, tables: str | Path) -> Path:
        """Write ``tables/<FILE>`` atomically; returns its path."""
        path = Path(tables) / self.FILE
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, json.dumps(self.to_json(), indent=1, default=str))
        return path

    @classmethod
    def read(cls, tables: str | Path) -> Any:
        """The record in ``tables/<FILE>``; None when the stage has not written one. A file that is not a JSON
        object of this record raises :class:`omcrl.runs.CorruptFile` naming it."""
        path = Path(tables) / cls.FILE
        if not path.exists():
            return None
        try:
            d = json.loads(path.read_text(encoding="utf-8"))
            if not isinstance(d, dict):
                raise ValueError(f"a JSON {type(d).__name__}, not an object")
            return cls.from_json(d)
        except (OSError, ValueError, TypeError) as e:
            raise CorruptFile(f"{path} is not a readable {cls.__name__} ({' '.join(str(e).split())[:120]})") from None


@dataclass
class RunNumbers:
    """Key numbers of a training run (:func:`omcrl.viz.rl.run_summary`): env steps, s, steps/s, fractions."""

    steps: float | None = None
    train_time_s: float | None = None
    steps_per_s: float | None = None
    final_success_rate: float | None = None
    best_success_rate: float | None = None
    final_return: float | None = None
    final_alpha: float | None = None


@dataclass
class DataRecord(StageRecord):
    """Notebook 01: the pretraining dataset (episodes, env steps, MB, s; success rate a fraction)."""

    FILE: ClassVar[str] = "data_summary.json"
    file: str = ""
    episodes: int = 0
    steps: int = 0
    per_source: dict = field(default_factory=dict)
    outcomes: dict = field(default_factory=dict)
    pilot_success_rate: float | None = None
    fingerprint: str = ""
    file_mb: float = 0.0
    wall_time_s_this_run: float = 0.0
    skipped: bool = False


@dataclass
class PretrainRecord(StageRecord):
    """Notebook 02: per encoder (``OMC``, ``CURL``) its run and final metrics; the linear probe's R² per encoder.

    JSON: ``{<encoder>: {...}, ..., "probe_r2": {<encoder or "random">: {<target>: R², "mean_r2": ...}}}``.
    """

    FILE: ClassVar[str] = "pretrain_summary.json"
    encoders: dict[str, dict] = field(default_factory=dict)
    probe_r2: dict[str, dict] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {**self.encoders, "probe_r2": self.probe_r2}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> PretrainRecord:
        enc = {k: v for k, v in d.items() if k != "probe_r2" and isinstance(v, dict)}
        return cls(encoders=enc, probe_r2=d.get("probe_r2") or {})


@dataclass
class OracleRecord(RunNumbers, StageRecord):
    """Notebook 03: the oracle's run (its :class:`RunNumbers`) and its evaluation in box (``eval_box``: SR %,
    SPL, CR %, episodes, ...)."""

    FILE: ClassVar[str] = "oracle_summary.json"
    final_path: str = ""
    reused: bool = False
    eval_box: dict = field(default_factory=dict)


@dataclass
class StudentRecord(StageRecord):
    """Notebook 04: the guided (``ours``) and unguided (``ours-noOT``) students: each run's numbers
    (:class:`RunNumbers` as a dict with ``final_path``), box SR % per method, the evaluation's size and time."""

    FILE: ClassVar[str] = "student_summary.json"
    encoder_path: str = ""
    oracle_path: str = ""
    guided: dict = field(default_factory=dict)
    unguided: dict = field(default_factory=dict)
    box_SR: dict = field(default_factory=dict)  # the paper's metric name
    guided_beats_unguided_box_SR: bool | None = None
    eval_episodes_per_scene: int = 0
    eval_wall_s: float = 0.0
    table_csv: str = ""


@dataclass
class BaselinesRecord(StageRecord):
    """Notebook 05: the baselines' runs (``runs``: ``method/seed<k>`` -> final policy) and wall time per method, s."""

    FILE: ClassVar[str] = "baselines_summary.json"
    seeds: list = field(default_factory=list)
    wall_s: dict = field(default_factory=dict)
    runs: dict = field(default_factory=dict)


@dataclass
class Table1Record(StageRecord):
    """Notebook 07: Table I's evaluation (seeds, episodes per scene, wall time s), its SR % per ``method/scene``,
    the runs it lacked, the claim ledger's verdict per claim (rows of ``ledger``:
    :func:`omcrl.eval.verdicts.verdict_counts`) and the files written. ``claims`` holds the v1 reference's
    orderings (SR differences per scene), as they were published; new records leave it empty."""

    FILE: ClassVar[str] = "table1_summary.json"
    seeds: list = field(default_factory=list)
    episodes_per_scene: int = 0
    eval_wall_s: float = 0.0
    missing_runs: list = field(default_factory=list)
    SR: dict = field(default_factory=dict)
    claims: list = field(default_factory=list)
    ledger: list = field(default_factory=list)
    files: dict = field(default_factory=dict)


@dataclass
class DeployRecord(StageRecord):
    """Notebook 09: the exported policy (``onnx``), torch/ONNX parity, latency per runtime (ms), the simulated
    flight's end and the fake Tello's video-cut test (s from the cut to landing)."""

    FILE: ClassVar[str] = "deploy_summary.json"
    method: str = ""
    onnx: str = ""
    parity: dict = field(default_factory=dict)
    latency: dict = field(default_factory=dict)
    sim_flight: dict = field(default_factory=dict)
    fake_tello_video_cut: dict = field(default_factory=dict)


RECORDS: tuple[type[StageRecord], ...] = (
    DataRecord,
    PretrainRecord,
    OracleRecord,
    StudentRecord,
    BaselinesRecord,
    Table1Record,
    DeployRecord,
)

__all__ = [
    "RECORDS",
    "BaselinesRecord",
    "DataRecord",
    "DeployRecord",
    "OracleRecord",
    "PretrainRecord",
    "RunNumbers",
    "StageRecord",
    "StudentRecord",
    "Table1Record",
]
