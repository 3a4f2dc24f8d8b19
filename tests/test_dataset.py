"""HDF5 trajectory dataset and sequence sampler."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
import torch

from omcrl.data import DatasetError, DatasetWriter, EpisodeBuffer, SequenceSampler, open_dataset
from omcrl.data.dataset import make_synthetic_dataset

torch.set_num_threads(1)


def _episode(T: int, S: int, value: int = 0) -> dict:
    return {
        "rgb": np.full((T, 3, S, S), value, np.uint8),
        "depth": np.ones((T, S, S), np.float32),
        "state": np.zeros((T, 12), np.float32),
        "privileged": np.zeros((T, 6), np.float32),
        "action": np.zeros((T, 3), np.float32),
        "reward": np.zeros(T, np.float32),
        "done": np.zeros(T, bool),
    }


def test_roundtrip_and_metadata(tmp_path):
    p = make_synthetic_dataset(tmp_path / "d.h5", n_episodes=3, length=[5, 7, 9], image_size=16, pattern="ids")
    with open_dataset(p, image_size=16, frame_stack=3) as ds:
        assert len(ds) == 3 and ds.episode_lengths.tolist() == [5, 7, 9] and ds.n_steps == 21
        assert ds.read(1, "rgb").shape == (7, 3, 16, 16) and ds.read(1, "rgb").dtype == np.uint8
        assert ds.read(2, "depth").shape == (9, 16, 16)
        assert ds.read(0, "done")[-1] and not ds.read(0, "done")[0]
        assert ds.env_config == {"synthetic": "ids"} and ds.kit_version
        s = ds.summary()
        assert s["per_source"] == {
            "pilot": {"episodes": 2, "steps": 14},
            "random": {"episodes": 1, "steps": 7},
        }
        assert ds.episode_attrs(2)["seed"] == 2
        fp = ds.fingerprint
        assert len(fp) == 12
    with open_dataset(p) as ds:
        assert ds.fingerprint == fp  # stable across opens
    with h5py.File(p, "r") as h5:
        assert h5["ep_000000/rgb"].chunks == (1, 3, 16, 16) and h5["ep_000000/rgb"].compression


def test_new_file_keeps_finished_episodes_and_leaves_no_temporary(tmp_path):
    # A new file is valid from its first moment and holds every finished episode (a kill loses nothing
    # finished); a writer that fails before finishing any episode leaves nothing behind.
    p = tmp_path / "d.h5"
    with DatasetWriter(p, 8, 2, {}) as w:
        assert p.exists()
        w.add_episode(**_episode(4, 8), scene="box", seed=0, source="pilot")
    q = tmp_path / "e.h5"
    with pytest.raises(RuntimeError, match="boom"), DatasetWriter(q, 8, 2, {}) as w:
        w.add_episode(**_episode(4, 8), scene="box", seed=0, source="pilot")
        raise RuntimeError("boom")
    with open_dataset(q) as ds:
        assert len(ds) == 1  # the finished episode survived the failure
    r = tmp_path / "f.h5"
    with pytest.raises(RuntimeError, match="boom"), DatasetWriter(r, 8, 2, {}):
        raise RuntimeError("boom")
    assert sorted(x.name for x in tmp_path.iterdir()) == ["d.h5", "e.h5"]  # no empty file, no temp left


def test_killed_new_collection_keeps_its_episodes_and_stale_temporaries_go(tmp_path):
    # Before: a new file lived under a temporary name until close, so kill -9 lost every episode and left a
    # hidden .tmp file that was never removed.
    import subprocess
    import sys
    import textwrap

    p = tmp_path / "d.h5"
    code = textwrap.dedent(
        f"""
        import os, numpy as np
        from omcrl.data.dataset import DatasetWriter
        w = DatasetWriter({str(p)!r}, 8, 2, {{}})
        for i in range(3):
            T = 4
            w.add_episode(rgb=np.full((T, 3, 8, 8), i, np.uint8), depth=np.zeros((T, 8, 8), np.float32),
                          state=np.zeros((T, 12), np.float32), privileged=np.zeros((T, 6), np.float32),
                          action=np.zeros((T, 3), np.float32), reward=np.zeros(T, np.float32),
                          done=np.zeros(T, bool), scene="box", seed=i, source="pilot")
        g = w._h5.create_group("ep_000003")  # half of a fourth episode, then the process dies
        g.create_dataset("rgb", data=np.zeros((2, 3, 8, 8), np.uint8))
        w._h5.flush()
        os._exit(9)
        """
    )
    assert subprocess.run([sys.executable, "-c", code]).returncode == 9
    (tmp_path / ".d.h5.stale.tmp").write_bytes(b"left by a killed writer")
    with open_dataset(p) as ds:
        assert len(ds) == 3
    with DatasetWriter(p, 8, 2, {}) as w:
        assert w.add_episode(**_episode(4, 8, value=9), scene="box", seed=3, source="pilot") == 3
    with open_dataset(p) as ds:
        assert ds.episode_lengths.tolist() == [4, 4, 4, 4] and (ds.read(3, "rgb") == 9).all()
    assert sorted(x.name for x in tmp_path.iterdir()) == ["d.h5"]


def test_append_keeps_earlier_episodes_and_drops_half_written(tmp_path):
    p = tmp_path / "d.h5"
    with DatasetWriter(p, 8, 2, {}) as w:
        w.add_episode(**_episode(4, 8, value=7), scene="box", seed=0, source="pilot")
    # A crash mid-episode leaves a group whose index is >= n_episodes.
    with h5py.File(p, "a") as h5:
        h5.create_group("ep_000001").create_dataset("rgb", data=np.zeros((2, 3, 8, 8), np.uint8))
    with open_dataset(p) as ds:
        assert len(ds) == 1
    with DatasetWriter(p, 8, 2, {}) as w:
        assert w.add_episode(**_episode(3, 8, value=9), scene="box", seed=1, source="random") == 1
    with open_dataset(p) as ds:
        assert ds.episode_lengths.tolist() == [4, 3]
        assert (ds.read(0, "rgb") == 7).all() and (ds.read(1, "rgb") == 9).all()
    with pytest.raises(DatasetError, match=r"image_size.*16"):
        DatasetWriter(p, 16, 2, {})


def test_validation_errors(tmp_path):
    with pytest.raises(DatasetError, match=r"nope\.h5.*does not exist"):
        open_dataset(tmp_path / "nope.h5")
    p = make_synthetic_dataset(tmp_path / "d.h5", n_episodes=2, length=5, image_size=16, frame_stack=3)
    with pytest.raises(DatasetError, match=r"d\.h5.*'image_size' expected 32, got 16"):
        open_dataset(p, image_size=32)
    with pytest.raises(DatasetError, match=r"d\.h5.*'frame_stack' expected 4, got 3"):
        open_dataset(p, frame_stack=4)
    with pytest.raises(DatasetError, match=r"image_size' expected 12"):
        SequenceSampler(open_dataset(p), 2, 3, crop=(12, 10))


def test_truncated_file_clear_error_and_untouched(tmp_path):
    p = make_synthetic_dataset(tmp_path / "d.h5", n_episodes=3, length=10, image_size=16)
    data = p.read_bytes()
    bad = tmp_path / "bad.h5"
    bad.write_bytes(data[: len(data) // 2])
    before = bad.read_bytes()
    with pytest.raises(DatasetError, match=r"bad\.h5.*truncated or corrupt"):
        open_dataset(bad)
    assert bad.read_bytes() == before
    garbage = tmp_path / "garbage.h5"
    garbage.write_bytes(b"not hdf5 at all" * 10)
    with pytest.raises(DatasetError, match=r"garbage\.h5"):
        open_dataset(garbage)


def test_sampler_never_crosses_episodes_and_pads_start(tmp_path):
    p = make_synthetic_dataset(tmp_path / "d.h5", n_episodes=5, length=[4, 9, 6, 12, 7], image_size=12, pattern="ids")
    L, T = 3, 4
    s = SequenceSampler(open_dataset(p), batch_size=8, seq_len=T, frame_stack=L, crop=(12, 10), seed=1)
    seen_start = False
    for _ in range(30):
        x, idx = s.sample_sequences(return_index=True)
        assert x.shape == (8, T, 3 * L, 10, 10) and x.dtype == torch.uint8
        for b in range(8):
            ep, t0 = idx[b]
            assert (x[b, :, 0::3] == ep).all()  # channel 0 of every frame = episode id
            t_frames = x[b, :, 1::3, 0, 0].numpy()  # (T, L) step of each frame
            want = np.clip(np.arange(t0, t0 + T)[:, None] + np.arange(-L + 1, 1)[None, :], 0, None)
            np.testing.assert_array_equal(t_frames, want)
            assert t0 + T <= s.ds.episode_lengths[ep]
            seen_start |= t0 == 0
    assert seen_start
    for stride in (0, 2):
        a, b = s.sample_pairs(16, stride=stride)
        assert (a[:, 0::3] == b[:, 0::3]).all()
        np.testing.assert_array_equal(b[:, -2, 0, 0].numpy() - a[:, -2, 0, 0].numpy(), stride)
    assert s.sample_stacks(5).shape == (5, 3 * L, 10, 10)


def test_sequence_stride_spaces_the_stacks_and_stays_inside_the_episode(tmp_path):
    p = make_synthetic_dataset(tmp_path / "d.h5", n_episodes=3, length=[5, 12, 9], image_size=12, pattern="ids")
    s = SequenceSampler(open_dataset(p), batch_size=16, seq_len=3, frame_stack=2, crop=(12, 12), seed=0, seq_stride=4)
    for _ in range(10):
        x, idx = s.sample_sequences(return_index=True)
        for b, (ep, t0) in enumerate(idx):
            # The newest frame of each stack is t0, t0 + 4, t0 + 8; the window of 9 steps fits the episode.
            np.testing.assert_array_equal(x[b, :, -2, 0, 0].numpy(), t0 + 4 * np.arange(3))
            assert ep != 0 and t0 + 8 < s.ds.episode_lengths[ep]  # episode 0 (5 steps) is too short
    with pytest.raises(DatasetError, match=r"no episode has >= 25 steps \(seq_len=3, seq_stride=12"):
        SequenceSampler(open_dataset(p), 2, 3, crop=(12, 12), seq_stride=12)
    with pytest.raises(ValueError, match="seq_stride"):
        SequenceSampler(open_dataset(p), 2, 3, crop=(12, 12), seq_stride=0)


def test_crop_offset_shared_by_frames_of_a_stack(tmp_path):
    S = 12
    yy, xx = np.mgrid[:S, :S]
    with DatasetWriter(tmp_path / "d.h5", S, 3, {}) as w:
        e = _episode(6, S)
        e["rgb"][:] = (xx + S * yy).astype(np.uint8)
        w.add_episode(**e, scene="box", seed=0, source="pilot")
    s = SequenceSampler(open_dataset(tmp_path / "d.h5"), 4, 3, 3, crop=(S, 8), seed=0)
    x = s.sample_sequences().numpy()
    corner = x[..., 0, 0]  # (B, T, 3L): offset of the crop
    assert (corner == corner[..., :1]).all()  # same offset for all frames/channels of a stack
    assert len(np.unique(corner)) > 1  # but different across stacks
    np.testing.assert_array_equal(x[..., 1, 1], corner + S + 1)


def test_same_seed_same_batches(tmp_path):
    p = make_synthetic_dataset(tmp_path / "d.h5", n_episodes=4, length=15, image_size=16)
    ds = open_dataset(p)
    a = SequenceSampler(ds, 4, 5, crop=(16, 12), seed=3)
    b = SequenceSampler(ds, 4, 5, crop=(16, 12), seed=3, cache_episodes=2)
    c = SequenceSampler(ds, 4, 5, crop=(16, 12), seed=4)
    for _ in range(3):
        xa, xb, xc = a.sample_sequences(), b.sample_sequences(), c.sample_sequences()
        assert torch.equal(xa, xb) and not torch.equal(xa, xc)
        assert all(torch.equal(u, v) for u, v in zip(a.sample_pairs(3, 1), b.sample_pairs(3, 1)))


def test_episode_buffer_takes_newest_frame():
    buf = EpisodeBuffer()
    for t in range(3):
        obs = {
            "rgb": np.stack([np.full((3, 8, 8), max(t - k, 0), np.uint8) for k in (2, 1, 0)]),
            "depth": np.full((3, 8, 8), float(t), np.float32),
            "state": np.zeros(12),
            "privileged": np.ones(6),
        }
        buf.add(obs, np.zeros(3), 0.5, t == 2)
    arr = buf.arrays()
    assert arr["rgb"][:, 0, 0, 0].tolist() == [0, 1, 2] and arr["depth"][:, 0, 0].tolist() == [0, 1, 2]
    assert arr["done"].tolist() == [False, False, True] and len(buf) == 3
