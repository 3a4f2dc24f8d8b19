"""Sequence sampler for masked contrastive pretraining (paper IV-B) and the CURL baselines.

Every sample lives inside one episode. Frames are read from disk per batch (bounded memory; an optional small
LRU cache of whole episodes trades memory for speed), so a dataset larger than RAM works.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np
import torch

from omcrl.data.dataset import DatasetError, TrajectoryDataset


class SequenceSampler:
    """Random batches of observation-stack sequences, CURL pairs and stray stacks.

    Parameters
    ----------
    dataset : an open :class:`TrajectoryDataset`.
    batch_size : B, sequences per batch.
    seq_len : T, stacks per sequence. Episodes shorter than a window ((T - 1) · seq_stride + 1 steps) are never
        used for sequences.
    frame_stack : L, frames per stack (default: the dataset's).
    crop : ``(crop_from, crop_to)``; ``crop_from`` must equal the stored image size. Each stack gets its own
        random crop offset, shared by its L frames (CURL-style).
    seed : same seed → same batches.
    cache_episodes : keep the rgb of this many most recently used episodes in memory (0 = read every time).
    seq_stride : env steps between consecutive stacks of a sequence (1 = consecutive steps, the paper's
        sequences; k > 1 samples the trajectory at 1/k of the control rate).

    Notes
    -----
    Windows are drawn uniformly over all valid (episode, start) pairs, so long episodes are not under-sampled.
    The state of the random generator is :attr:`rng`; save ``rng.bit_generator.state`` to resume exactly.
    """

    def __init__(
        self,
        dataset: TrajectoryDataset,
        batch_size: int,
        seq_len: int,
        frame_stack: int | None = None,
        crop: tuple[int, int] | None = None,
        seed: int = 0,
        cache_episodes: int = 0,
        seq_stride: int = 1,
    ) -> None:
        self.ds = dataset
        self.B, self.T = int(batch_size), int(seq_len)
        if int(seq_stride) < 1:
            raise ValueError(f"seq_stride: expected an integer >= 1, got {seq_stride}")
        self.stride = int(seq_stride)
        span = (self.T - 1) * self.stride + 1  # env steps one sequence covers
        self.L = int(frame_stack or dataset.frame_stack)
        crop_from, crop_to = crop if crop is not None else (dataset.image_size, dataset.image_size)
        if int(crop_from) != dataset.image_size:
            raise DatasetError(
                f"dataset {dataset.path}: field 'image_size' expected {crop_from} "
                f"(pretrain.crop_from), got {dataset.image_size}"
            )
        if not 0 < crop_to <= crop_from:
            raise ValueError(f"crop: got {crop}, need 0 < crop_to <= crop_from")
        self.crop_from, self.crop_to = int(crop_from), int(crop_to)
        self.rng = np.random.default_rng(seed)
        self.cache_episodes = int(cache_episodes)
        self._cache: OrderedDict[int, np.ndarray] = OrderedDict()
        lengths = dataset.episode_lengths
        if len(lengths) == 0:
            raise DatasetError(f"dataset {dataset.path}: contains no complete episode")
        self._seq_w = np.clip(lengths - span + 1, 0, None).astype(np.float64)
        if self._seq_w.sum() == 0:
            raise DatasetError(
                f"dataset {dataset.path}: no episode has >= {span} steps (seq_len={self.T}, seq_stride={self.stride}; "
                f"longest has {int(lengths.max())})"
            )
        self._step_w = lengths.astype(np.float64)

    # -- reading
    def _frames(self, ep: int, lo: int, hi: int) -> tuple[np.ndarray, int]:
        """rgb rows ``lo:hi`` of episode ``ep`` (or the whole cached episode) and its first row index."""
        if self.cache_episodes <= 0:
            return self.ds.read(ep, "rgb", lo, hi), lo
        if ep in self._cache:
            self._cache.move_to_end(ep)
        else:
            self._cache[ep] = self.ds.read(ep, "rgb")
            while len(self._cache) > self.cache_episodes:
                self._cache.popitem(last=False)
        return self._cache[ep], 0

    def _stacks(self, ep: int, ts: np.ndarray) -> np.ndarray:
        lo = max(int(ts.min()) - self.L + 1, 0)
        frames, start = self._frames(ep, lo, int(ts.max()) + 1)
        return self.ds.read_stacks(ep, ts, self.L, frames=frames, frames_start=start)

    def _crop(self, x: np.ndarray) -> np.ndarray:
        """Random crop (n, C, S, S) → (n, C, s, s), one offset per stack."""
        n, s, S = len(x), self.crop_to, self.crop_from
        if s == S:
            return x
        oy = self.rng.integers(0, S - s + 1, size=n)
        ox = self.rng.integers(0, S - s + 1, size=n)
        rows = oy[:, None] + np.arange(s)[None, :]  # (n, s)
        cols = ox[:, None] + np.arange(s)[None, :]
        return x[
            np.arange(n)[:, None, None, None],
            np.arange(x.shape[1])[None, :, None, None],
            rows[:, None, :, None],
            cols[:, None, None, :],
        ]

    def _episodes(self, n: int, weights: np.ndarray) -> np.ndarray:
        return self.rng.choice(len(weights), size=n, p=weights / weights.sum())

    # -- public sampling
    def sample_sequences(
        self, batch_size: int | None = None, return_index: bool = False
    ) -> torch.Tensor | tuple[torch.Tensor, np.ndarray]:
        """B sequences of T stacks ``seq_stride`` steps apart: uint8 (B, T, 3L, crop_to, crop_to).

        With ``return_index`` also returns int64 (B, 2) rows of (episode, first step).
        """
        B = int(batch_size or self.B)
        eps = self._episodes(B, self._seq_w)
        starts = np.array([self.rng.integers(0, int(self._seq_w[e])) for e in eps], dtype=np.int64)
        out = []
        for ep, t0 in zip(eps, starts):
            out.append(self._crop(self._stacks(int(ep), t0 + self.stride * np.arange(self.T))))
        x = torch.from_numpy(np.stack(out))
        return (x, np.stack([eps, starts], axis=1)) if return_index else x

    def _random_steps(self, n: int, gap: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """n (episode, t) with t + gap inside the episode; episodes weighted by usable steps."""
        w = np.clip(self._step_w - gap, 0, None)
        if w.sum() == 0:
            raise DatasetError(f"dataset {self.ds.path}: no episode longer than cons_stride={gap}")
        eps = self._episodes(n, w)
        ts = np.array([self.rng.integers(0, int(w[e])) for e in eps], dtype=np.int64)
        return eps, ts

    def sample_stacks(self, n: int) -> torch.Tensor:
        """n stacks from anywhere in the dataset, each randomly cropped: uint8 (n, 3L, crop_to, crop_to).

        Used as the pool for masking's "replace h_i with another h_j" case.
        """
        eps, ts = self._random_steps(n)
        x = np.concatenate([self._stacks(int(e), np.array([t])) for e, t in zip(eps, ts)])
        return torch.from_numpy(self._crop(x))

    def sample_pairs(self, n: int | None = None, stride: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
        """Anchor/positive pairs for CURL: each uint8 (n, 3L, crop_to, crop_to), independently cropped.

        ``stride=0``: two crops of the same stack h_t (CURL). ``stride=k>0``: h_t and h_{t+k} of the same
        episode (CURL-cons).
        """
        n = int(n or self.B)
        eps, ts = self._random_steps(n, gap=stride)
        a, p = [], []
        for e, t in zip(eps, ts):
            s = self._stacks(int(e), np.array([t, t + stride]))
            a.append(s[0])
            p.append(s[1])
        return torch.from_numpy(self._crop(np.stack(a))), torch.from_numpy(self._crop(np.stack(p)))
