"""Data collection: a tiny vectorised run writes a valid dataset, resumes by appending, refuses mismatches."""

from __future__ import annotations

import hashlib
from collections import Counter

import numpy as np
import pytest
import torch

from omcrl.config import ConfigError, load_config
from omcrl.data import DatasetError, open_dataset
from omcrl.data.collect import assign_sources, collect_dataset, dataset_path, episode_outcomes

torch.set_num_threads(1)


def _cfg(tmp_path, episodes: int = 4, image_size: int = 32, extra: tuple[str, ...] = ()):
    return load_config(
        "smoke",
        overrides=[
            f"data.file={tmp_path}/{{preset}}/box.h5",
            f"data.episodes={episodes}",
            "data.n_envs=2",
            "data.max_steps=12",
            "data.mix={pilot: 0.5, random: 0.5, policy: 0.0}",
            f"env.image_size={image_size}",
            f"pretrain.crop_from={image_size}",
            f"pretrain.crop_to={image_size - 4}",
            *extra,
        ],
    )


def _episode_digest(ds, ep: int) -> str:
    h = hashlib.sha256()
    for name in ("rgb", "depth", "state", "privileged", "action", "reward", "done"):
        h.update(np.ascontiguousarray(ds.read(ep, name)).tobytes())
    return h.hexdigest()


def test_assign_sources_is_prefix_stable_and_follows_the_mix():
    mix = {"pilot": 0.7, "random": 0.3, "policy": 0.0}
    a = assign_sources(mix, 50, seed=3)
    assert assign_sources(mix, 20, seed=3) == a[:20]
    c = Counter(a)
    assert abs(c["pilot"] - 35) <= 1 and abs(c["random"] - 15) <= 1 and "policy" not in c
    assert assign_sources(mix, 50, seed=4) != a  # the seed changes the interleaving
    with pytest.raises(ConfigError, match="data.mix"):
        assign_sources({"pilot": 0.0}, 3, 0)


def test_collect_writes_resumes_and_refuses_mismatch(tmp_path):
    cfg = _cfg(tmp_path, episodes=4)
    res = collect_dataset(cfg, progress=False)
    path = dataset_path(cfg)
    assert res.path == path and res.added == 4 and res.episodes == 4 and path.is_file()
    want = assign_sources(cfg.data.mix, 6, cfg.seed)
    with open_dataset(path, image_size=32, frame_stack=cfg.env.frame_stack) as ds:
        assert len(ds) == 4
        assert ds.sources == want[:4]
        assert all(1 <= n <= 12 for n in ds.episode_lengths)
        assert ds.read(0, "rgb").shape == (ds.episode_lengths[0], 3, 32, 32)
        assert ds.read(0, "depth").shape == (ds.episode_lengths[0], 32, 32)
        assert ds.read_stacks(0, [0, 1]).shape == (2, 3 * cfg.env.frame_stack, 32, 32)
        assert ds.read(0, "done")[-1] and not ds.read(0, "done")[:-1].any()
        assert ds.episode_attrs(0)["scene"] == "box-v2"  # data.scene: the default suite's training scene
        acts = np.concatenate([ds.read(e, "action") for e in range(4)])
        assert np.all(np.abs(acts) <= 1.0) and acts.std() > 0
        assert len(episode_outcomes(ds)) == 4
        before = [_episode_digest(ds, e) for e in range(4)]
    assert sum(res.per_source.values()) == 4

    # Enough episodes already: nothing happens.
    assert collect_dataset(cfg, progress=False).skipped

    # More episodes: the first four are untouched, two are appended with the next sources of the sequence.
    cfg6 = _cfg(tmp_path, episodes=6)
    res6 = collect_dataset(cfg6, progress=False)
    assert res6.added == 2 and res6.episodes == 6
    with open_dataset(path) as ds:
        assert len(ds) == 6 and ds.sources == want
        assert [_episode_digest(ds, e) for e in range(4)] == before

    # Another image size: a clear error and the file is left byte-for-byte as it was.
    blob = path.read_bytes()
    bad = _cfg(tmp_path, episodes=8, image_size=36)
    with pytest.raises(DatasetError, match="image_size.*expected 36.*got 32"):
        collect_dataset(bad, progress=False)
    assert path.read_bytes() == blob


def test_collect_checks_config_before_work(tmp_path):
    cfg = _cfg(tmp_path, extra=("pretrain.crop_from=40",))
    with pytest.raises(ConfigError, match="crop_from"):
        collect_dataset(cfg, progress=False)
    cfg = _cfg(tmp_path, extra=("data.mix={pilot: 0.5, policy: 0.5}",))
    with pytest.raises(ConfigError, match="no policy"):
        collect_dataset(cfg, progress=False)
    assert not dataset_path(cfg).exists()


def test_collect_with_a_given_policy(tmp_path):
    calls = []

    def policy(obs, info):
        assert obs["rgb"].shape == (3, 3, 32, 32) and "pose" in info
        calls.append(1)
        return np.array([0.5, 0.0, 0.1])

    cfg = _cfg(tmp_path, episodes=2, extra=("data.mix={policy: 1.0}",))
    res = collect_dataset(cfg, policy=policy, progress=False)
    assert res.per_source == {"policy": 2} and len(calls) >= res.steps_added
    with open_dataset(dataset_path(cfg)) as ds:
        np.testing.assert_allclose(ds.read(0, "action")[0], [0.5, 0.0, 0.1], atol=1e-6)
