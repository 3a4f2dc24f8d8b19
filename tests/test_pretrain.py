"""Masking, contrastive losses, momentum keys, the training stage and the probe."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest
import torch

from omcrl.config import load_config
from omcrl.data import open_dataset
from omcrl.data.dataset import make_synthetic_dataset
from omcrl.models import load_encoder, random_encoder
from omcrl.pretrain import (
    OP_KEEP,
    OP_NONE,
    OP_REPLACE,
    OP_ZERO,
    ContrastiveLearner,
    apply_mask_ops,
    bilinear_info_nce,
    masked_info_nce,
    method_name,
    pretrain_encoder,
    probe,
    sample_mask_ops,
    transformer_lr_factor,
)
from omcrl.pretrain.probe import TARGETS
from omcrl.utils.io import file_digest

torch.set_num_threads(1)


def _cfg(tmp_path, **pre):
    base = {
        "crop_from": 20,
        "crop_to": 16,
        "batch_size": 4,
        "seq_len": 6,
        "feature_dim": 16,
        "proj_hidden": 16,
        "transformer_blocks": 1,
        "transformer_ffn": 32,
        "iterations": 6,
        "checkpoint_every": 3,
        "warmup_steps": 5,
        "num_threads": 1,
    }
    over = {
        "results_dir": str(tmp_path / "res"),
        "env": {"image_size": 20, "frame_stack": 3},
        "pretrain": {**base, **pre},
    }
    return load_config("smoke", overrides=over)


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return make_synthetic_dataset(tmp_path_factory.mktemp("d") / "d.h5", n_episodes=6, length=24, image_size=20)


# ---------------------------------------------------------------- masking
@pytest.mark.parametrize("rho", [0.1, 0.5, 0.9])
def test_mask_rate_and_split(rho):
    g = torch.Generator().manual_seed(0)
    mask, ops = sample_mask_ops((100, 100), rho, g)
    assert abs(mask.float().mean().item() - rho) < 0.02
    assert ((ops != OP_NONE) == mask).all()
    sel = ops[mask]
    for op, share in ((OP_ZERO, 0.8), (OP_REPLACE, 0.1), (OP_KEEP, 0.1)):
        assert abs((sel == op).float().mean().item() - share) < 0.03


def test_apply_mask_ops():
    B, T = 3, 5
    seq = (torch.arange(B * T, dtype=torch.uint8) + 1).view(B, T, 1, 1, 1).expand(B, T, 2, 4, 4).contiguous()
    ops = torch.tensor([OP_NONE, OP_ZERO, OP_REPLACE, OP_KEEP, OP_REPLACE]).repeat(B, 1)
    g = torch.Generator().manual_seed(0)
    out = apply_mask_ops(seq, ops, None, g)
    assert torch.equal(out[ops == OP_NONE], seq[ops == OP_NONE])
    assert torch.equal(out[ops == OP_KEEP], seq[ops == OP_KEEP])
    assert (out[ops == OP_ZERO] == 0).all()
    rep = out[ops == OP_REPLACE][:, 0, 0, 0]
    assert (rep != seq[ops == OP_REPLACE][:, 0, 0, 0]).all()  # j != i
    for _ in range(50):  # j != i also over many draws
        o = apply_mask_ops(seq, ops, None, g)
        assert (o[ops == OP_REPLACE] != seq[ops == OP_REPLACE]).all()
    pool = torch.full((4, 2, 4, 4), 200, dtype=torch.uint8)
    assert (apply_mask_ops(seq, ops, pool, g)[ops == OP_REPLACE] == 200).all()


# ---------------------------------------------------------------- losses
def _ref_info_nce(q, k, mask, tau, batch_negatives):
    q, k, mask = q.double().numpy(), k.double().numpy(), mask.numpy()
    B, T, _ = q.shape
    cos = lambda a, b: a @ b / (np.linalg.norm(a) * np.linalg.norm(b))  # noqa: E731
    losses, hits = [], []
    for b in range(B):
        for i in range(T):
            if not mask[b, i]:
                continue
            cands = [(bb, j) for bb in (range(B) if batch_negatives else [b]) for j in range(T)]
            s = np.array([cos(q[b, i], k[bb, j]) / tau for bb, j in cands])
            pos = cands.index((b, i))
            losses.append(-(s[pos] - math.log(np.exp(s).sum())))
            hits.append(int(np.argmax(s) == pos))
    return np.mean(losses), np.mean(hits)


@pytest.mark.parametrize("batch_negatives", [False, True])
def test_masked_info_nce_matches_reference(batch_negatives):
    g = torch.Generator().manual_seed(1)
    q, k = torch.randn(3, 5, 7, generator=g), torch.randn(3, 5, 7, generator=g)
    mask = torch.rand(3, 5, generator=g) < 0.5
    loss, acc = masked_info_nce(q, k, mask, 0.1, batch_negatives)
    ref_loss, ref_acc = _ref_info_nce(q, k, mask, 0.1, batch_negatives)
    assert loss.item() == pytest.approx(ref_loss, rel=1e-5) and acc.item() == pytest.approx(ref_acc)
    z, a = masked_info_nce(q.requires_grad_(), k, torch.zeros(3, 5, dtype=torch.bool), 0.1, batch_negatives)
    assert z.item() == 0 and math.isnan(a.item())
    z.backward()  # an all-unmasked batch still gives a usable graph


def test_bilinear_info_nce_matches_reference():
    g = torch.Generator().manual_seed(2)
    q, k, W = torch.randn(4, 3, generator=g), torch.randn(4, 3, generator=g), torch.randn(3, 3, generator=g)
    loss, _ = bilinear_info_nce(q, k, W)
    Q, K, M = q.double().numpy(), k.double().numpy(), W.double().numpy()
    ref = np.mean([-(Q[i] @ M @ K[i] - math.log(sum(math.exp(Q[i] @ M @ K[j]) for j in range(4)))) for i in range(4)])
    assert loss.item() == pytest.approx(ref, rel=1e-5)


def test_lr_schedule():
    assert transformer_lr_factor(1, 100) == pytest.approx(0.01)
    assert transformer_lr_factor(50, 100) == pytest.approx(0.5)
    assert transformer_lr_factor(100, 100) == pytest.approx(1.0)
    assert transformer_lr_factor(400, 100) == pytest.approx(0.5)
    assert transformer_lr_factor(4, 0) == pytest.approx(0.5)


# ---------------------------------------------------------------- learner
@pytest.mark.parametrize("dual", [False, True])
def test_momentum_update_exact_and_keys_get_no_gradient(tmp_path, dual):
    cfg = _cfg(tmp_path, dual_transformer=dual, momentum=0.05)
    torch.manual_seed(0)
    lr = ContrastiveLearner(cfg.pretrain, 3)
    key_params = [*lr.f_k.parameters(), *lr.phi_k.parameters()] + ([*lr.xi_k.parameters()] if dual else [])
    assert all(not p.requires_grad for p in key_params)
    seq = torch.randint(0, 256, (2, 6, 9, 16, 16), dtype=torch.uint8)
    loss, _ = lr.omc_loss(seq, torch.Generator().manual_seed(0))
    loss.backward()
    assert all(p.grad is None for p in key_params)
    assert lr.f.fc.weight.grad is not None and lr.xi.blocks[0].q.weight.grad is not None
    with torch.no_grad():  # move the online nets away from the keys
        for p in [*lr.f.parameters(), *lr.phi.parameters(), *lr.xi.parameters()]:
            p.add_(torch.randn_like(p))
    pairs = [(lr.f, lr.f_k), (lr.phi, lr.phi_k)] + ([(lr.xi, lr.xi_k)] if dual else [])
    before = [(p.clone(), pk.clone()) for o, k in pairs for p, pk in zip(o.parameters(), k.parameters())]
    lr.momentum_update()
    after = [pk for _, k in pairs for pk in k.parameters()]
    for (p, pk), new in zip(before, after):
        torch.testing.assert_close(new, 0.05 * p + 0.95 * pk, rtol=0, atol=1e-6)


def test_omc_loss_decreases(data, tmp_path):
    """A few dozen iterations of the real training loop lower the loss on synthetic moving-square data."""
    cfg = _cfg(
        tmp_path,
        crop_to=20,
        batch_size=8,
        feature_dim=32,
        proj_hidden=32,
        transformer_ffn=64,
        iterations=80,
        checkpoint_every=80,
    )
    r = pretrain_encoder(cfg, data, progress=False)
    loss = pd.read_csv(r.metrics_path).query("metric == 'loss'")["value"].to_numpy()
    assert len(loss) == 80
    assert loss[-20:].mean() < loss[:10].mean() - 0.15


# ---------------------------------------------------------------- the stage
def test_run_outputs_cache_and_artifact(data, tmp_path):
    cfg = _cfg(tmp_path)
    r = pretrain_encoder(cfg, data, progress=False)
    assert r.run_dir.parent.parent == tmp_path / "res" / "smoke" / "runs" / "pretrain" and not r.skipped
    assert r.run_dir.name == "seed0" and r.run_dir.parent.name.startswith("omc-")
    assert {p.name for p in r.run_dir.iterdir()} >= {
        "config.yaml",
        "metrics.csv",
        "checkpoint.pt",
        "encoder.pt",
        "run.json",
    }
    assert not (r.run_dir / "done.json").exists()  # finished as every run is: run.json holds the artifact's digest
    record = json.loads((r.run_dir / "run.json").read_text())
    assert record["artifact_digest"] == file_digest(r.encoder_path) and record["iterations"] == 6
    assert record["dataset_fingerprint"] == open_dataset(data).fingerprint
    assert record["dataset"] == str(data)  # the data it was made of, not its last checkpoint (a loop variable did)
    df = pd.read_csv(r.metrics_path)
    assert list(df.columns) == ["step", "metric", "value"]
    assert set(df.metric) >= {"loss", "accuracy", "lr_encoder", "lr_transformer"}
    assert sorted(df.query("metric == 'loss'").step) == list(range(1, 7))
    # TensorBoard events as for RL: one scalar per metric and iteration.
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    ev = EventAccumulator(str(r.run_dir / "tb"))
    ev.Reload()
    assert [e.step for e in ev.Scalars("loss")] == list(range(1, 7))
    assert set(ev.Tags()["scalars"]) >= {"loss", "accuracy", "lr_encoder", "lr_transformer"}
    enc = load_encoder(r.encoder_path, image_size=20, frame_stack=3)
    assert enc.meta["dataset_fingerprint"] == open_dataset(data).fingerprint
    assert enc(torch.zeros(2, 9, 20, 20, dtype=torch.uint8)).shape == (2, 16)
    mtime = r.encoder_path.stat().st_mtime_ns
    again = pretrain_encoder(cfg, data, progress=False)
    assert again.skipped and r.encoder_path.stat().st_mtime_ns == mtime
    # A corrupted finished encoder is not trusted: it is rebuilt (here from the final checkpoint), with a warning.
    good = r.encoder_path.read_bytes()
    r.encoder_path.write_bytes(good[: len(good) // 2])
    with pytest.warns(UserWarning, match="does not match the digest"):
        fixed = pretrain_encoder(cfg, data, progress=False)
    assert not fixed.skipped and r.encoder_path.read_bytes() == good


def test_interrupted_run_resumes_to_identical_result(data, tmp_path):
    cfg_a = _cfg(tmp_path / "a")
    straight = pretrain_encoder(cfg_a, data, progress=False)
    cfg_b = _cfg(tmp_path / "b")
    part = pretrain_encoder(cfg_b, data, progress=False, stop_after=4)  # checkpoint at 3, iteration 4 is lost
    assert part.iterations == 4 and part.start == 0 and not (part.run_dir / "encoder.pt").exists()
    resumed = pretrain_encoder(cfg_b, data, progress=False)
    # It says where it began, so that a sweep times it against the iterations it ran, not the whole budget.
    assert resumed.iterations == 6 and resumed.start == 3 and not resumed.skipped
    sa = torch.load(straight.encoder_path, weights_only=True)
    sb = torch.load(resumed.encoder_path, weights_only=True)
    for key in ("f", "phi"):
        for name in sa[key]:
            assert torch.equal(sa[key][name], sb[key][name]), name
    da, db = pd.read_csv(straight.metrics_path), pd.read_csv(resumed.metrics_path)
    pd.testing.assert_frame_equal(da, db)


@pytest.mark.parametrize(
    "pre, name",
    [
        ({"method": "curl", "use_projection": False}, "curl"),
        ({"method": "curl"}, "curl-phi"),
        ({"method": "curl_cons", "cons_stride": 2, "use_projection": False}, "curl_cons-stride2"),
        (
            {"use_projection": False, "dual_transformer": True, "batch_negatives": False, "mask_prob": 0.3},
            "omc-rho0.3-nophi-dualT-seqneg",
        ),
        ({"seq_stride": 2}, "omc-stride2"),
    ],
)
def test_variants_run(data, tmp_path, pre, name):
    cfg = _cfg(tmp_path, iterations=3, **pre)
    assert method_name(cfg.pretrain) == name
    r = pretrain_encoder(cfg, data, progress=False)
    assert r.name == name and math.isfinite(r.final_loss)
    enc = load_encoder(r.encoder_path)
    assert enc.meta["use_projection"] == cfg.pretrain.use_projection and enc.feature_dim == 16


# ---------------------------------------------------------------- probe
class _OracleFeatures(torch.nn.Module):
    """Reads the synthetic square's centre from the newest frame: a probe on it must score R² ≈ 1."""

    frame_stack, crop_from, crop_to = 3, 20, 20

    def forward(self, x):
        on = (x[:, -3] == 255).float()  # (N, H, W) square of the newest frame
        ys, xs = torch.meshgrid(torch.arange(20.0), torch.arange(20.0), indexing="ij")
        cy, cx = [(on * g).sum((1, 2)) / on.sum((1, 2)) / 20 - 0.5 for g in (ys, xs)]
        ang = torch.atan2(cx, cy)
        return torch.stack([cy, cx, torch.hypot(cy, cx), torch.sin(ang), torch.cos(ang)], 1)


def test_probe_pipeline_and_random_encoder(data, tmp_path):
    ds = open_dataset(data)
    out = probe(_OracleFeatures(), ds, n_samples=200, seed=0)
    assert set(out) == {*TARGETS, "n_train", "n_test"}
    assert out["n_train"] + out["n_test"] == 200
    assert min(out["distance"], out["bearing_sin"], out["bearing_cos"]) > 0.9  # targets align with frames
    rand = probe(random_encoder(_cfg(tmp_path), seed=0), ds, n_samples=120, seed=0)
    assert all(np.isfinite(rand[k]) for k in ("distance", "bearing_sin", "bearing_cos"))


def test_finished_run_skips_without_its_dataset_and_lost_metrics_are_reported(data, tmp_path):
    # Before: skipping a finished run opened the dataset (missing file -> error), and a metrics.csv deleted
    # before a resume silently lost the history and wrote NaN into the run's record.
    import json
    import shutil

    moved = tmp_path / "copy.h5"
    shutil.copy(data, moved)
    cfg = _cfg(tmp_path)
    first = pretrain_encoder(cfg, moved, progress=False)
    moved.unlink()
    again = pretrain_encoder(cfg, moved, progress=False)
    assert again.skipped and again.encoder_path == first.encoder_path
    # Resume with metrics.csv gone: a warning says what is lost; run.json stays valid JSON.
    cfg_b = _cfg(tmp_path / "b")
    part = pretrain_encoder(cfg_b, data, progress=False, stop_after=4)
    (part.run_dir / "metrics.csv").unlink()
    with pytest.warns(UserWarning, match="history is lost"):
        done = pretrain_encoder(cfg_b, data, progress=False)
    assert done.iterations == 6
    record = json.loads((done.run_dir / "run.json").read_text())  # strict JSON: no NaN
    assert record["final_loss"] is None or np.isfinite(record["final_loss"])


def test_color_jitter_changes_colours_not_masks_and_is_seeded():
    from omcrl.pretrain.learner import color_jitter

    seq = torch.full((4, 3, 9, 8, 8), 100, dtype=torch.uint8)
    seq[1, 2] = 0  # a masked (all-zero) stack
    out = color_jitter(seq, 0.5, torch.Generator().manual_seed(0))
    assert out.shape == seq.shape and out.dtype == torch.float32
    assert float(out.min()) >= 0 and float(out.max()) <= 255
    assert torch.all(out[1, 2] == 0)  # masks stay masks
    gains = out[:, 0, :, 0, 0] / 100.0  # (B, 3L)
    # One gain per sequence and RGB channel, shared by every stack and every frame of a stack ...
    torch.testing.assert_close(out[[0, 2, 3]], out[[0, 2, 3], :1].expand(3, 3, 9, 8, 8))
    torch.testing.assert_close(gains[:, 0:3], gains[:, 3:6])
    torch.testing.assert_close(gains[:, 0:3], gains[:, 6:9])
    # ... within [(1 - s)², (1 + s)²], and different between sequences.
    assert float(gains.min()) >= 0.25 - 1e-6 and float(gains.max()) <= 2.25 + 1e-6
    assert not torch.allclose(gains[0], gains[2])
    torch.testing.assert_close(out, color_jitter(seq, 0.5, torch.Generator().manual_seed(0)))
    assert not torch.allclose(out, color_jitter(seq, 0.5, torch.Generator().manual_seed(1)))


@pytest.mark.parametrize("field, value", [("color_jitter", 0.4), ("seq_stride", 3)])
def test_fields_added_later_keep_run_keys_at_their_default(tmp_path, field, value):
    from omcrl.pretrain.train import pretrain_run

    base = load_config("smoke", overrides=[f"results_dir={tmp_path}"])
    on = load_config("smoke", overrides=[f"results_dir={tmp_path}", f"pretrain.{field}={value}"])
    assert field not in pretrain_run(base).identity["pretrain"]
    assert pretrain_run(on).identity["pretrain"][field] == value and pretrain_run(on).key != pretrain_run(base).key


def test_every_pretraining_method_is_one_objective_chosen_once():
    """The OMC/CURL decision lives in one table: each ``pretrain.method`` the config allows is an Objective, OMC
    alone samples masked sequences (and owns ξ), CURL-cons alone pairs consecutive stacks; an unknown method is
    refused by name."""
    from dataclasses import fields
    from types import SimpleNamespace

    from omcrl.config import UNTRAINED_ENCODERS, PretrainConfig
    from omcrl.pretrain import OBJECTIVES, ContrastiveLearner, objective

    choices = next(f for f in fields(PretrainConfig) if f.name == "method").metadata["choices"]
    assert set(choices) == set(OBJECTIVES) | set(UNTRAINED_ENCODERS)  # the controls' encoders have no objective
    assert [m for m, o in OBJECTIVES.items() if o.sequences] == ["omc"]
    assert [m for m, o in OBJECTIVES.items() if o.consecutive] == ["curl_cons"]
    for m in OBJECTIVES:
        p = PretrainConfig(method=m, feature_dim=8, crop_to=16, proj_hidden=8)
        learner = ContrastiveLearner(p, 2)
        assert (learner.xi is not None) == objective(p).sequences and (learner.W is None) == objective(p).sequences
    with pytest.raises(ValueError, match="'byol'"):
        objective(SimpleNamespace(method="byol"))


def test_the_controls_encoders_are_the_initialisation_and_a_constant(tmp_path):
    """Issue 75: ``random`` is f+φ exactly as OMC pretraining initialises them at the seed (before its first
    iteration), made without data; ``blind`` gives (B, d) zeros for any input; both are finished runs found again."""
    from dataclasses import replace

    from omcrl.pipeline.recipes import pretrain_method
    from omcrl.pretrain import ContrastiveLearner

    cfg = load_config("smoke", overrides=[f"results_dir={tmp_path}", f"data.file={tmp_path / 'none.h5'}"])
    r = pretrain_method(cfg, "ours-random", progress=False)
    assert r.iterations == 0 and not cfg.data_path.exists()  # no data was collected or needed
    torch.manual_seed(cfg.seed)
    init = ContrastiveLearner(replace(cfg.pretrain, method="omc"), cfg.env.frame_stack)
    enc = load_encoder(r.encoder_path)
    for name, t in init.f.state_dict().items():
        assert torch.equal(enc.f.state_dict()[name], t), name
    x = torch.randint(0, 256, (4, 3 * enc.frame_stack, enc.crop_from, enc.crop_from), dtype=torch.uint8)
    assert not torch.equal(enc(x)[0], enc(x)[1])
    b = pretrain_method(cfg, "ours-blind", progress=False)
    z = load_encoder(b.encoder_path)(x)
    assert z.shape == (4, enc.feature_dim) and torch.count_nonzero(z) == 0
    assert pretrain_method(cfg, "ours-blind", progress=False).skipped
