"""Hardening (issue 11): each test reproduces a failure found by probing the kit and fails without its fix."""

from __future__ import annotations

import os
import stat

import numpy as np
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
    from omcrl.pipeline import train_method
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


# ---------------------------------------------------------------- the env among its peers
def test_env_follows_gymnasium_conventions():
    import gymnasium as gym
    import numpy as np
    from gymnasium.utils.env_checker import check_env

    from omcrl.config import ConfigError
    from omcrl.envs import GYM_IDS, make_env

    for scene, gym_id in GYM_IDS.items():
        env = gym.make(gym_id, image_size=32, max_steps=20)
        assert env.unwrapped.scene == scene
        check_env(env.unwrapped, skip_render_check=False)
        env.close()
    # render_mode is validated; render() without one returns None as gymnasium prescribes.
    with pytest.raises(ConfigError, match="render_mode"):
        make_env("box", image_size=32, render_mode="human")
    env = make_env("box", image_size=32, render_mode=None)
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode"):
        assert env.render() is None
    # Actions must be (3,): (1, 3) and (3, 1) hide batching mistakes.
    for bad in (np.zeros((1, 3)), np.zeros((3, 1))):
        with pytest.raises(ValueError, match=r"expected shape \(3,\)"):
            env.step(bad)
    env.close()
    with pytest.raises(RuntimeError, match="closed"):
        env.step(np.zeros(3))


def test_vector_env_closed_and_dropped():
    import gc

    import numpy as np

    from omcrl.envs import make_vec_env

    venv = make_vec_env("box", 2, seed=0, image_size=32)
    venv.reset(seed=0)
    procs = list(venv._procs)
    venv.close()
    with pytest.raises(RuntimeError, match="closed vector env"):
        venv.step(np.zeros((2, 3), np.float32))
    # Dropped without close(): its worker must not outlive it.
    venv = make_vec_env("box", 2, seed=0, image_size=32)
    procs = list(venv._procs)
    del venv
    gc.collect()
    for p in procs:
        p.join(timeout=5)
        assert not p.is_alive()


def test_stable_baselines3_trains_on_the_wrapped_env():
    import warnings

    from stable_baselines3 import PPO
    from stable_baselines3.common.env_checker import check_env
    from stable_baselines3.common.evaluation import evaluate_policy

    from omcrl.envs import SB3Wrapper, make_env

    env = SB3Wrapper(make_env("box", seed=0, image_size=48, max_steps=40))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # SB3's checker must have nothing to say
        check_env(env, warn=True)
    model = PPO("MultiInputPolicy", env, n_steps=128, batch_size=64, n_epochs=1, seed=0, device="cpu")
    model.learn(total_timesteps=256)
    from stable_baselines3.common.monitor import Monitor

    mean, std = evaluate_policy(model, Monitor(env), n_eval_episodes=2)
    assert np.isfinite(mean)
    env.close()


def test_texture_cache_location_errors_and_fallback(tmp_path, monkeypatch):
    # Before: OMCRL_CACHE pointing at a file crashed deep inside PyBullet's texture loading.
    from omcrl.envs import textures

    f = tmp_path / "a_file"
    f.write_text("x")
    monkeypatch.setenv("OMCRL_CACHE", str(f))
    with pytest.raises(NotADirectoryError, match="OMCRL_CACHE"):
        textures.cache_dir()
    monkeypatch.setenv("OMCRL_CACHE", str(tmp_path / "cache"))
    assert textures.cache_dir() == tmp_path / "cache" / "textures" / "v1"
    assert os.path.exists(textures.texture_file("wood"))
    # No usable home folder: the cache falls back to the temporary folder instead of failing.
    monkeypatch.delenv("OMCRL_CACHE")
    monkeypatch.setenv("HOME", str(f))
    d = textures.cache_dir()
    assert d.is_dir() and "omcrl-cache-" in str(d)


# ---------------------------------------------------------------- errors a user can read
@pytest.mark.parametrize(
    ("override", "match"),
    [
        ("env.goal_distance=[3,", r"'env.goal_distance=\[3,'.*not valid YAML"),
        ("data.mix={pilot: abc}", r"'data.mix'.*non-negative numbers"),
        ("data.file=data/{foo}.h5", r"'data.file'.*only placeholders allowed are \{preset\} and \{seed\}"),
        ("eval.scenes=[]", r"'eval.scenes'.*at least one"),
        ("env.goal_reward=.inf", r"'env.goal_reward'.*finite number"),
        ("env.goal_distance=[6,3]", r"'env.goal_distance'.*min <= max"),
        ("env.goal_distance=[30,40]", r"'env.goal_distance'.*arena_half"),
        ("preset=paper", r"'preset'.*--preset paper"),
    ],
)
def test_config_values_that_escaped_validation(override, match):
    from omcrl.config import ConfigError

    with pytest.raises(ConfigError, match=match):
        load_config("smoke", overrides=[override])


def test_config_file_must_be_yaml_text(tmp_path):
    from omcrl.config import ConfigError

    (tmp_path / "bin.yaml").write_bytes(bytes(range(256)))
    with pytest.raises(ConfigError, match="not a text file"):
        load_config("smoke", path=tmp_path / "bin.yaml")
    with pytest.raises(ConfigError, match="not a file"):
        load_config("smoke", path=tmp_path)


def test_env_options_are_validated_when_the_env_is_built():
    from omcrl.config import ConfigError
    from omcrl.envs import make_env

    with pytest.raises(ConfigError, match=r"goal_distance.*\(30.0, 40.0\)"):
        make_env("box", image_size=32, goal_distance=(30, 40))  # before: failed at reset, unnamed
    sphere = {"kind": "sphere", "position": (2, 2), "size": ()}
    with pytest.raises(ConfigError, match=r"layout\[0\] sphere: size needs \(radius,\)"):
        make_env("box", image_size=32, layout=[sphere])
    with pytest.raises(ConfigError, match=r"layout\[0\] sphere"):
        make_env("box", image_size=32, layout=[{**sphere, "size": (0.3, 9.0)}])  # extra values were dropped
    for bad, field in (({"hue": "red"}, "hue"), ({"switch_step": 2.5}, "switch_step"), ({"ambient": 3}, "ambient")):
        with pytest.raises(ConfigError, match=f"disturbance.{field}"):
            make_env("box", image_size=32, disturbance=bad)


def test_messages_show_plain_numbers():
    from omcrl.config import ConfigError

    with pytest.raises(ConfigError) as e:
        load_config("smoke", overrides={"env": {"max_speed": np.float64(99.0)}})
    assert "np.float64" not in str(e.value) and "99.0" in str(e.value)


def test_cli_prints_one_line_for_expected_failures(tmp_path, repo_root):
    # Before: a corrupt checkpoint printed a long traceback that ended by suggesting weights_only=False.
    import subprocess
    import sys

    from omcrl.rl.train import oracle_run

    cfg = load_config("smoke", overrides=[f"results_dir={tmp_path}"])
    run = oracle_run(cfg)
    run.dir.mkdir(parents=True)
    (run.dir / "checkpoint.pt").write_bytes(b"not a torch file")
    cmd = [sys.executable, "-m", "omcrl", "oracle", "--preset", "smoke", "--set", f"results_dir={tmp_path}"]
    r = subprocess.run(cmd, cwd=repo_root, capture_output=True, text=True)
    lines = [x for x in r.stderr.splitlines() if x.startswith("error")]
    assert r.returncode == 1 and len(lines) == 1 and "checkpoint.pt" in lines[0]
    assert "Traceback" not in r.stderr and "weights_only=False" not in r.stderr
    r = subprocess.run([*cmd, "--debug"], cwd=repo_root, capture_output=True, text=True)
    assert r.returncode != 0 and "Traceback" in r.stderr
    r = subprocess.run([*cmd[:6], "--set", "env.goal_distance=[3,"], cwd=repo_root, capture_output=True, text=True)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "not valid YAML" in r.stderr


# ---------------------------------------------------------------- a full disk
_DISK_FULL = r"""
import json, subprocess, sys
from omcrl.config import load_config
from omcrl.data import collect
from omcrl.data.dataset import DatasetError, open_dataset

mnt = sys.argv[1]
subprocess.run(["mount", "-t", "tmpfs", "-o", "size=700k", "tmpfs", mnt], check=True)
cfg = load_config("smoke", overrides=[f"data.file={mnt}/box.h5", "data.episodes=12", f"results_dir={mnt}"])
out = {}
try:
    collect.collect_dataset(cfg, progress=False)
    out["error"] = None
except DatasetError as e:
    out["error"] = str(e)
with open_dataset(f"{mnt}/box.h5") as ds:
    out["kept"] = len(ds)
subprocess.run(["mount", "-o", "remount,size=30m", mnt], check=True)
r = collect.collect_dataset(cfg, progress=False)
out["after"], out["added"] = r.episodes, r.added
print(json.dumps(out))
"""


def test_full_disk_keeps_complete_episodes_and_the_rerun_appends(tmp_path, repo_root):
    # Before: ENOSPC during an append left a file that collect could no longer open ("addr overflow").
    import json
    import shutil
    import subprocess
    import sys

    mnt = tmp_path / "mnt"
    mnt.mkdir()
    if shutil.which("unshare") is None or subprocess.run(["unshare", "-m", "true"]).returncode != 0:
        pytest.skip("no private mount namespace here (needs unshare and root) for a size-limited tmpfs")
    r = subprocess.run(
        ["unshare", "-m", sys.executable, "-c", _DISK_FULL, str(mnt)], cwd=repo_root, capture_output=True, text=True
    )
    assert r.returncode == 0, r.stderr[-3000:]
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out["error"] is not None and "disk is full" in out["error"] and "box.h5" in out["error"], out
    assert out["kept"] >= 1
    assert out["after"] == 12 and out["added"] == 12 - out["kept"]


def test_hybrid_apf_plans_away_from_the_arena_edge():
    # Before: bound to the env it left the arena in barrier on held-out seeds 1000015 and 1000018 (steps 126, 128).
    from omcrl.envs import make_env
    from omcrl.planners import HybridAPF

    cfg = load_config("quick").env
    env = make_env("barrier", seed=0, config=cfg)
    pilot = HybridAPF(cfg).bind(env)
    try:
        for seed in (1000015, 1000018):
            obs, info = env.reset(seed=seed)
            pilot.reset(info)
            done = False
            while not done:
                obs, _, term, trunc, info = env.step(pilot.act(obs, info))
                done = term or trunc
            assert not info["metrics"]["out_of_arena"], seed
    finally:
        env.close()


@pytest.mark.slow
def test_kill_minus_nine_at_random_moments_of_every_stage(tmp_path, repo_root):
    """scripts/kill_test.py with 10 kills per stage: every rerun finishes and keeps each stage's promise."""
    import json
    import subprocess
    import sys

    out = tmp_path / "kills.json"
    cmd = [sys.executable, "scripts/kill_test.py", "--kills", "10", "--work", str(tmp_path / "w"), "--json", str(out)]
    r = subprocess.run(cmd, cwd=repo_root, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    rows = json.loads(out.read_text())
    assert [x["stage"] for x in rows] == ["collect", "pretrain", "oracle", "student", "evaluate"]
    for x in rows:
        assert x["promise_held"], x
        assert x["kills"] >= 1, x  # at least one kill landed mid-run
    assert next(x for x in rows if x["stage"] == "pretrain")["bit_identical"]
    assert next(x for x in rows if x["stage"] == "evaluate")["bit_identical"]
