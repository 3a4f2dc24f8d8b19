"""Hardening (issue 11): each test reproduces a failure found by probing the kit and fails without its fix."""

from __future__ import annotations

import os
import stat

import pytest
import torch

from omcrl.config import load_config
from omcrl.rl import CheckpointError
from omcrl.utils.io import atomic_write_text, current_umask


class _Payload:
    """Unpickling this runs code (creates a marker file): what a crafted checkpoint would do."""

    def __init__(self, marker: str) -> None:
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


def test_crafted_checkpoint_in_a_run_folder_is_refused_without_running_code(tmp_path):
    # Before: checkpoint.pt was loaded with weights_only=False, so `python -m omcrl oracle` ran its code.
    from omcrl.rl.methods import train_method
    from omcrl.rl.train import oracle_run

    cfg = load_config("smoke", overrides=[f"results_dir={tmp_path}"])
    run = oracle_run(cfg)
    run.dir.mkdir(parents=True)
    marker = tmp_path / "pwned"
    torch.save({"step": 0, "evil": _Payload(str(marker))}, run.dir / "checkpoint.pt")
    with pytest.raises(CheckpointError) as e:
        train_method(cfg, "oracle", progress=False)
    msg = str(e.value)
    assert "checkpoint.pt" in msg and "refuses to unpickle" in msg and "weights_only=False" not in msg
    assert not marker.exists()
    # The same for a policy file and an encoder handed to the kit.
    from omcrl.models import EncoderError, load_encoder
    from omcrl.rl import load_policy

    torch.save({"x": _Payload(str(marker))}, tmp_path / "final.pt")
    with pytest.raises(CheckpointError, match="final.pt"):
        load_policy(tmp_path / "final.pt")
    with pytest.raises(EncoderError, match="final.pt"):
        load_encoder(tmp_path / "final.pt")
    assert not marker.exists()


def test_artifacts_get_the_umask_permissions(tmp_path):
    # Before: files written through mkstemp kept mode 0600 whatever the umask.
    old = os.umask(0o022)
    try:
        atomic_write_text(tmp_path / "a.txt", "x")
        assert stat.S_IMODE((tmp_path / "a.txt").stat().st_mode) == 0o644
        os.umask(0o077)
        assert current_umask() == 0o077
        atomic_write_text(tmp_path / "b.txt", "x")
        assert stat.S_IMODE((tmp_path / "b.txt").stat().st_mode) == 0o600
    finally:
        os.umask(old)


def test_policy_file_is_self_contained(tmp_path, monkeypatch):
    # Before: the policy kept a cwd-relative encoder path, so it did not load from another directory.
    import numpy as np

    from omcrl.envs import make_env
    from omcrl.models import ActorCritic, random_encoder, save_encoder
    from omcrl.models.features import make_student_features
    from omcrl.rl import load_policy
    from omcrl.rl.policy import policy_payload

    cfg = load_config("smoke")
    monkeypatch.chdir(tmp_path)
    (tmp_path / "enc").mkdir()
    enc = random_encoder(cfg, seed=1)
    save_encoder("enc/encoder.pt", enc.f, enc.phi, cfg)  # a relative path, as the CLI gives
    env = make_env("box", seed=0, config=cfg.env)
    space = env.observation_space
    obs, _ = env.reset(seed=0)
    env.close()
    agent = ActorCritic(make_student_features("enc/encoder.pt", space), 3, 16)
    torch.save(policy_payload(agent, {k: list(s.shape) for k, s in space.spaces.items()}, 0), "final.pt")
    want = load_policy("final.pt").act(obs)
    (tmp_path / "enc" / "encoder.pt").unlink()  # the encoder's own file is gone
    other = tmp_path / "elsewhere"
    other.mkdir()
    monkeypatch.chdir(other)
    np.testing.assert_array_equal(load_policy(tmp_path / "final.pt").act(obs), want)
