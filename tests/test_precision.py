"""bfloat16 precision (issue: speed, second pass): resolution, run identity, a bf16 chain end to end, ONNX parity."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from omcrl.config import ConfigError, load_config
from omcrl.utils import precision as prec


def test_precision_resolves_from_the_hardware(monkeypatch):
    assert prec.resolve_precision("fp32") == "fp32" and prec.resolve_precision("bf16") == "bf16"
    native, why = prec.native_bf16("cpu")
    assert prec.resolve_precision("auto") == ("bf16" if native else "fp32") and "flag" in why
    monkeypatch.setattr(prec, "cpu_flags", lambda: frozenset({"avx2", "avx512f"}))
    assert prec.native_bf16("cpu") == (False, "none of the CPU flags avx512_bf16, amx_bf16 in /proc/cpuinfo")
    assert prec.resolve_precision("auto", "cpu") == "fp32"
    monkeypatch.setattr(prec, "cpu_flags", lambda: frozenset({"avx512_bf16"}))
    assert prec.resolve_precision("auto", torch.device("cpu")) == "bf16"
    with pytest.raises(ConfigError, match="precision"):
        prec.resolve_precision("fp16")
    with pytest.raises(ConfigError, match="rl.precision.*fp16"):
        load_config("smoke", overrides=["rl.precision=fp16"])


def test_training_passes_run_in_bf16_inference_in_fp32_outputs_float32():
    from omcrl.models.actor_critic import ActorCritic
    from omcrl.models.features import IdentityFeatures

    agent = ActorCritic(IdentityFeatures(5), 3, 16)
    x = {"x": torch.randn(4, 5)}
    ref = agent(x)
    agent.precision = "bf16"
    got = agent(x)
    assert all(b.dtype == torch.float32 for b in got)
    for a, b in ((ref[0], got[0]), (ref[2], got[2])):  # mean and value; std is the fp32 parameter
        assert not torch.equal(a, b) and torch.allclose(a, b, atol=0.05)  # rounded in bf16, close to fp32
    assert torch.equal(ref[1], got[1])
    with torch.no_grad():  # inference stays fp32 whatever the precision
        for a, b in zip(ref, agent(x)):
            assert torch.equal(a, b)
    assert agent.spec()["precision"] == "bf16" and "precision" not in ActorCritic(IdentityFeatures(5), 3).spec()


def test_bf16_and_fp32_runs_have_different_keys_and_auto_is_what_it_resolves_to(monkeypatch):
    from omcrl.pretrain.train import pretrain_run
    from omcrl.rl.train import oracle_run

    monkeypatch.setattr(prec, "cpu_flags", lambda: frozenset({"amx_bf16"}))
    keys, runs = {}, {}
    for p in ("fp32", "bf16", "auto"):
        cfg = load_config("quick", overrides=[f"rl.precision={p}", f"pretrain.precision={p}"])
        runs[p] = (oracle_run(cfg), pretrain_run(cfg))
        keys[p] = tuple(r.dir.parent.name for r in runs[p])
    assert keys["fp32"] != keys["bf16"] == keys["auto"]
    # fp32 is the default: its identities hold no precision; bf16 ones hold the resolved value.
    assert "precision" not in runs["fp32"][0].identity["rl"] and runs["auto"][0].identity["rl"]["precision"] == "bf16"
    assert runs["auto"][1].identity["pretrain"]["precision"] == "bf16"
    monkeypatch.setattr(prec, "cpu_flags", lambda: frozenset())
    cfg = load_config("quick", overrides=["rl.precision=auto", "pretrain.precision=auto"])
    assert (oracle_run(cfg).dir.parent.name, pretrain_run(cfg).dir.parent.name) == keys["fp32"]


def test_bf16_chain_trains_evaluates_and_exports_with_parity(tmp_path):
    """Collect, pretrain (OMC) and train end-to-end PPO in bf16 at smoke; evaluate; export to ONNX."""
    from omcrl.data.collect import collect_dataset as collect
    from omcrl.deploy import OnnxPolicy, export_onnx
    from omcrl.eval.stage import evaluate_methods
    from omcrl.pipeline import pretrain_method, train_method
    from omcrl.rl import load_policy

    cfg = load_config(
        "smoke",
        overrides=[f"results_dir={tmp_path}", f"data.file={tmp_path}/box.h5", "rl.precision=bf16",
                   "pretrain.precision=bf16", "eval.workers=1"],
    )  # fmt: skip
    collect(cfg, progress=False)
    enc = pretrain_method(cfg, "ours", progress=False)
    assert "precision" in (enc.run_dir / "run.json").read_text()
    res = train_method(cfg, "ppo", progress=False)
    pol = load_policy(res.final_path)
    assert pol.agent.precision == "bf16"
    ep = evaluate_methods(cfg, {"ppo": res.final_path}, ["box"], 2)
    assert len(ep) == 2 and ep.final_distance.notna().all()
    # The policy trained in bf16 acts in fp32 (its float32 master weights), as the exported graph does.
    onnx_pol = OnnxPolicy(export_onnx(res.run_dir))
    fp32 = load_policy(res.final_path)
    fp32.agent.precision = "fp32"
    rng = np.random.default_rng(0)
    gap_fp32 = gap_bf16 = 0.0
    for _ in range(50):
        obs = {
            "rgb": rng.integers(0, 256, (cfg.env.frame_stack, 3, 32, 32), dtype=np.uint8),
            "state": (rng.normal(size=12) * 3).astype(np.float32),
        }
        a = onnx_pol.act(obs)
        gap_fp32 = max(gap_fp32, float(np.abs(a - fp32.act(obs)).max()))
        gap_bf16 = max(gap_bf16, float(np.abs(a - pol.act(obs)).max()))
    assert gap_fp32 <= 1e-4, gap_fp32
    assert gap_bf16 <= 1e-4, gap_bf16


def test_precision_table_resolves_a_real_difference_and_not_noise():
    import pandas as pd

    from omcrl.eval.ablation import precision_table
    from omcrl.pipeline.grids import ABLATION_GRIDS, FULL_BUDGET_GRIDS, GRIDS

    rng = np.random.default_rng(0)
    rows = []
    for label, p in (("ours fp32", 0.9), ("ours bf16", 0.9), ("PPO fp32", 0.6), ("PPO bf16", 0.1)):
        for s in (0, 1):
            for i in range(50):
                row = {"label": label, "method": label.split()[0], "train_seed": s, "scene": "box-v0", "eval_seed": i}
                row.update(success=rng.random() < p, collision=False, final_distance=1.0, min_distance=0.5)
                rows.append({**row, "path_length": 5.0, "optimal_path_length": 5.0, "steps": 100})
    t = precision_table(pd.DataFrame(rows), reps=500).set_index("method")
    assert not t.loc["ours", "resolved"] and t.loc["ours", "lo"] < 0 < t.loc["ours", "hi"]
    assert t.loc["PPO", "resolved"] and t.loc["PPO", "hi"] < 0 and t.loc["PPO", "seeds"] == 2
    assert "precision" in GRIDS and "precision" in FULL_BUDGET_GRIDS and "precision" not in ABLATION_GRIDS
