"""HDF5 trajectory dataset for upstream pretraining (paper IV-B, "Data Collection").

Layout of one file::

    /                       attrs: format_version, image_size, frame_stack, env_config (JSON), kit_version,
                                   created (ISO UTC), n_episodes (written last, see below)
    /ep_000000              attrs: scene, seed, source ("pilot" | "random" | "policy"), steps
        rgb        uint8   (T, 3, H, W)   single frames (not stacks), one chunk per frame, compressed
        depth      float16 (T, H, W)      metres
        state      float32 (T, 12)        v (3, body), ω (3), θ (roll, pitch, yaw), Δp_goal (3, body)
        privileged float32 (T, 6)         Δp to nearest obstacle surface (3, body), Δp_goal (3, body)
        action     float32 (T, 3)         in [-1, 1]
        reward     float32 (T,)
        done       bool    (T,)
    /ep_000001 ...

Row ``t`` holds the newest frame of the observation the agent saw at step ``t``, the action it took and the
reward/done that followed. Stacks of ``L`` frames are rebuilt at read time
(:meth:`TrajectoryDataset.read_stacks`), padding before the episode start by repeating the first frame,
exactly like the environment does.

Crash safety: a new file is written under a temporary name and renamed when the writer closes. Appending to an
existing file adds groups and only then bumps the ``n_episodes`` attribute, so an episode half-written when
the process died has an index ``>= n_episodes``; readers ignore it and the next writer deletes it.
"""

from __future__ import annotations

import datetime as _dt
import errno
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import h5py
import numpy as np

import omcrl
from omcrl.envs.observation import PRIVILEGED_DIM, STATE_DIM
from omcrl.utils.io import current_umask

FORMAT_VERSION = 1
SOURCES = ("pilot", "random", "policy")
FIELDS = {  # name -> (dtype, shape after the time axis; "img" = image side)
    "rgb": (np.uint8, (3, "img", "img")),
    "depth": (np.float16, ("img", "img")),
    "state": (np.float32, (STATE_DIM,)),
    "privileged": (np.float32, (PRIVILEGED_DIM,)),
    "action": (np.float32, (3,)),
    "reward": (np.float32, ()),
    "done": (np.bool_, ()),
}


class DatasetError(RuntimeError):
    """A trajectory file is missing, corrupt or does not match what the caller expects (message names it)."""


_LOCKED = (
    "dataset {path} is locked by another process (HDF5 file locking: a `collect` is writing it); wait for it to "
    "finish, or stop it"
)


def _locked(e: OSError) -> bool:
    """Is this h5py error HDF5's file lock held by another process (not a damaged file)?"""
    text = str(e).lower()
    return "unable to lock file" in text or ("lock" in text and "resource temporarily unavailable" in text)


def episode_key(i: int) -> str:
    """Group name of episode ``i`` (``ep_000042``)."""
    return f"ep_{i:06d}"


def _expected_shape(name: str, image_size: int) -> tuple[int, ...]:
    return tuple(image_size if s == "img" else s for s in FIELDS[name][1])


# ---------------------------------------------------------------- writing
class EpisodeBuffer:
    """Accumulate one episode step by step from environment observations (single, not vector, env).

    Example
    -------
    >>> buf = EpisodeBuffer()
    >>> buf.add(obs, action, reward, done)      # obs as returned by env.reset / env.step *before* the action
    >>> writer.add_episode(**buf.arrays(), scene="box", seed=3, source="pilot")
    """

    def __init__(self) -> None:
        self.rows: dict[str, list[np.ndarray]] = {k: [] for k in FIELDS}

    def add(self, obs: dict, action: np.ndarray, reward: float, done: bool) -> None:
        """Store the newest frame of ``obs['rgb']`` (L, 3, H, W) / ``obs['depth']`` (L, H, W) and the step."""
        self.rows["rgb"].append(np.asarray(obs["rgb"])[-1])
        self.rows["depth"].append(np.asarray(obs["depth"])[-1])
        self.rows["state"].append(np.asarray(obs["state"], np.float32))
        self.rows["privileged"].append(np.asarray(obs["privileged"], np.float32))
        self.rows["action"].append(np.asarray(action, np.float32))
        self.rows["reward"].append(np.float32(reward))
        self.rows["done"].append(np.bool_(done))

    def __len__(self) -> int:
        return len(self.rows["action"])

    def arrays(self) -> dict[str, np.ndarray]:
        """The episode as ``{field: array (T, ...)}``, ready for :meth:`DatasetWriter.add_episode`."""
        return {k: np.stack(v) for k, v in self.rows.items()}


class DatasetWriter:
    """Write episodes to an HDF5 trajectory file (new, or appended to an existing compatible one).

    Every finished episode is durable: it is flushed and only then counted (the file attribute ``n_episodes``
    is written last), so a kill at any moment leaves a valid file with all finished episodes, which a rerun
    appends to. A new file is first created as an empty, valid file (under a temporary name, then renamed),
    so the path never holds a half-initialised file. Groups of an episode that was being written when the
    process died (index >= ``n_episodes``) are removed on the next open by copying the complete episodes into
    a fresh file (never by editing the damaged one in place, whose free-space records may be inconsistent
    after a full disk). A full disk raises :class:`DatasetError` naming the file; the file keeps its complete
    episodes.

    Parameters
    ----------
    path : target file.
    image_size : square image side H = W (px).
    frame_stack : L the data is meant to be used with (stored as metadata; stacks are rebuilt at read time).
    env_config : the environment configuration (JSON-able dict), stored as metadata.
    compression : ``"lzf"`` (fast, default) or ``"gzip"`` for the image datasets.
    """

    def __init__(
        self, path: str | Path, image_size: int, frame_stack: int, env_config: dict, compression: str = "lzf"
    ) -> None:
        self.path = Path(path)
        self.image_size = int(image_size)
        self.frame_stack = int(frame_stack)
        self.compression = compression
        self._h5: h5py.File | None = None
        self._broken = False
        self.path.parent.mkdir(parents=True, exist_ok=True)
        _remove_stale_temporaries(self.path)
        self.created = not self.path.exists()
        if self.created:
            self._create(env_config)
        self._open_for_append()

    def _create(self, env_config: dict) -> None:
        """An empty valid file under a temporary name, renamed into place."""

        fd, tmp = tempfile.mkstemp(dir=self.path.parent, prefix=f".{self.path.name}.", suffix=".tmp")
        os.fchmod(fd, 0o666 & ~current_umask())  # the finished file gets the umask's permissions, not 0600
        os.close(fd)
        try:
            with h5py.File(tmp, "w") as h5:
                a = h5.attrs
                a["format_version"] = FORMAT_VERSION
                a["image_size"] = self.image_size
                a["frame_stack"] = self.frame_stack
                a["env_config"] = json.dumps(env_config, sort_keys=True, default=str)
                a["kit_version"] = omcrl.__version__
                a["created"] = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
                a["n_episodes"] = 0
            os.replace(tmp, self.path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise

    def _open_for_append(self) -> None:
        try:
            h5 = h5py.File(self.path, "a")
        except OSError as e:
            if _locked(e):
                raise DatasetError(_LOCKED.format(path=self.path)) from None
            raise DatasetError(f"dataset {self.path}: cannot open for appending ({e})") from None
        for key, want in (("image_size", self.image_size), ("frame_stack", self.frame_stack)):
            got = int(h5.attrs.get(key, -1))
            if got != want:
                h5.close()
                raise DatasetError(
                    f"dataset {self.path}: cannot append, field '{key}' is {got} in the "
                    f"file but the writer was given {want}"
                )
        self.n_episodes = int(h5.attrs.get("n_episodes", 0))
        stray = [k for k in h5.keys() if k.startswith("ep_") and int(k[3:]) >= self.n_episodes]
        if stray:  # an episode a killed writer left half-written
            h5.close()
            _keep_complete(self.path, self.n_episodes)
            h5 = h5py.File(self.path, "a")
        self._h5 = h5

    def add_episode(
        self,
        *,
        rgb: np.ndarray,
        depth: np.ndarray,
        state: np.ndarray,
        privileged: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        done: np.ndarray,
        scene: str,
        seed: int,
        source: str,
    ) -> int:
        """Append one episode; arrays have a leading time axis T (shapes in the module docstring).

        Returns the episode index. ``n_episodes`` is updated only after all data is flushed.
        """
        if source not in SOURCES:
            raise ValueError(f"source: got {source!r}, allowed values are {list(SOURCES)}")
        data = {
            "rgb": rgb,
            "depth": depth,
            "state": state,
            "privileged": privileged,
            "action": action,
            "reward": reward,
            "done": done,
        }
        n = len(np.asarray(action))
        if n < 1:
            raise ValueError("an episode needs at least one step")
        arrays = {}
        for name, arr in data.items():
            arr = np.asarray(arr)
            want = (n, *_expected_shape(name, self.image_size))
            if arr.shape != want:
                raise ValueError(f"episode field '{name}': got shape {arr.shape}, expected {want}")
            arrays[name] = arr.astype(FIELDS[name][0], copy=False)
        if self._broken:
            raise DatasetError(f"dataset {self.path}: the writer failed earlier; run collect again to append")
        idx = self.n_episodes
        # Refuse before HDF5 meets a full disk: a write that fails inside HDF5 leaves its library state broken
        # (the file on disk keeps its complete episodes either way). Raw sizes over-estimate compressed ones.
        need = sum(a.nbytes for a in arrays.values()) + 256 * 1024
        free = shutil.disk_usage(self.path.parent).free
        if free < need:
            raise DatasetError(
                f"dataset {self.path}: the disk is full ({free / 2**20:.1f} MiB free, episode {idx} needs up to "
                f"{need / 2**20:.1f} MiB); the file keeps its {idx} complete episodes (free some space and run "
                "collect again to append from there)"
            )
        try:
            g = self._h5.create_group(episode_key(idx))
            for name, arr in arrays.items():
                # Fletcher-32 checksums on every chunk: a damaged episode fails its read (DatasetError) instead of
                # feeding wrong pixels to pretraining.
                if name in ("rgb", "depth"):
                    # One chunk per frame: a sequence read decompresses only the frames it needs.
                    g.create_dataset(
                        name, data=arr, chunks=(1, *arr.shape[1:]), compression=self.compression, fletcher32=True
                    )
                else:
                    g.create_dataset(name, data=arr, fletcher32=True)
            g.attrs["scene"] = str(scene)
            g.attrs["seed"] = int(seed)
            g.attrs["source"] = source
            g.attrs["steps"] = n
            self._h5.flush()
            self._h5.attrs["n_episodes"] = idx + 1  # last: marks the episode complete
            self._h5.flush()
        except (OSError, RuntimeError, ValueError) as e:
            self._broken = True
            full = getattr(e, "errno", None) == errno.ENOSPC or "No space left" in str(e)
            why = "the disk is full" if full else f"writing failed ({type(e).__name__}: {e})"
            raise DatasetError(
                f"dataset {self.path}: {why} while writing episode {idx}; the file keeps its {idx} complete "
                "episodes (free some space and run collect again to append from there)"
            ) from None
        self.n_episodes = idx + 1
        return idx

    def close(self, discard: bool = False) -> None:
        """Close the file. Finished episodes stay; ``discard`` removes a file this writer created and that holds
        no finished episode."""
        if self._h5 is None:
            return
        h5, self._h5 = self._h5, None
        try:
            h5.close()
        except Exception:  # after a full disk closing may fail too; the complete episodes are already on disk
            if not self._broken:
                raise
        if discard and self.created and self.n_episodes == 0:
            self.path.unlink(missing_ok=True)

    def __enter__(self) -> DatasetWriter:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        self.close(discard=exc_type is not None)

    def __del__(self) -> None:
        try:
            if getattr(self, "_h5", None) is not None:
                self.close(discard=True)
        except Exception:
            pass


def _remove_stale_temporaries(path: Path) -> None:
    """Delete ``.<name>.*.tmp`` files a killed writer of ``path`` left behind (empty skeletons or old copies)."""
    for tmp in path.parent.glob(f".{path.name}.*.tmp"):
        tmp.unlink(missing_ok=True)


def _keep_complete(path: Path, n: int) -> None:
    """Replace ``path`` by a fresh copy holding its attributes and its first ``n`` (complete) episodes."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.fchmod(fd, 0o666 & ~current_umask())
    os.close(fd)
    try:
        with h5py.File(path, "r") as src, h5py.File(tmp, "w") as dst:
            for k, v in src.attrs.items():
                dst.attrs[k] = v
            for i in range(n):
                src.copy(src[episode_key(i)], dst, name=episode_key(i))
        os.replace(tmp, path)
    except OSError as e:
        Path(tmp).unlink(missing_ok=True)
        raise DatasetError(f"dataset {path}: cannot recover its {n} complete episodes ({e})") from None


class PipeStream:
    """A pipe seen by numpy as a plain stream: ``np.lib.format`` reads and writes a real file with
    ``fromfile``/``tofile``, which need a seekable file and fail on a pipe."""

    def __init__(self, raw: Any) -> None:
        self.raw = raw

    def read(self, n: int = -1) -> bytes:
        return self.raw.read(n)

    def write(self, data: bytes) -> int:
        return self.raw.write(data)


class WriterProcess:
    """A :class:`DatasetWriter` in a process of its own, with the same interface (``add_episode``, ``close``,
    ``n_episodes``, ``created``, a context manager).

    Why a process: HDF5 that meets a full disk in the middle of a write can leave its library state broken, and
    the interpreter then crashed at exit (a segfault in 2 of 19 racing tries, ~100 lines of h5py noise). In a
    child the crash stays there: the collector reports one line (:class:`DatasetError`, naming the file and the
    complete episodes it keeps) and exits with an error; the file keeps every complete episode (each is flushed
    before it is counted), and a rerun appends to it.

    The child is ``python -m omcrl.data.writer_child`` (not :mod:`multiprocessing`, whose spawned children re-run a
    user's unguarded script): episodes go to its stdin as ``.npy`` arrays after a JSON header line, read back
    with ``allow_pickle=False``; replies are JSON lines on its stdout. It ends with its parent, and when its stdin
    closes. Starting it costs about half a second per collection.

    Parameters
    ----------
    as for :class:`DatasetWriter`.
    """

    def __init__(
        self, path: str | Path, image_size: int, frame_stack: int, env_config: dict, compression: str = "lzf"
    ) -> None:
        self.path = Path(path)
        self.n_episodes, self.created, self._done = 0, False, False
        self._stderr = tempfile.TemporaryFile()
        # The child imports the same omcrl as this process, wherever that came from (a checkout, an install, or a
        # copy Ray shipped to a cluster node with the job), so the package's folder goes first on its path.
        pkg_parent = str(Path(__file__).resolve().parents[2])
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [pkg_parent, os.environ.get("PYTHONPATH")]))}
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "omcrl.data.writer_child", str(os.getpid())],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self._stderr,
            env=env,
        )
        opening = {
            "path": str(self.path),
            "image_size": int(image_size),
            "frame_stack": int(frame_stack),
            "env_config": json.loads(json.dumps(env_config, default=str)),
            "compression": compression,
        }
        self._send(opening, "opening the file")
        reply = self._receive("opening the file")
        self.n_episodes, self.created = int(reply["n_episodes"]), bool(reply["created"])

    @property
    def pid(self) -> int:
        """The writer process's PID."""
        return self._proc.pid

    def _died(self, doing: str) -> DatasetError:
        try:
            code = self._proc.wait(timeout=10)
        except subprocess.TimeoutExpired:  # alive but out of step with us: end it, the file keeps what it has
            self._proc.kill()
            code = self._proc.wait()
        how = f"signal {-code}" if code < 0 else f"exit code {code}"
        self._done = True
        return DatasetError(
            f"dataset {self.path}: the writer process died ({how}) while {doing}; the file keeps its "
            f"{self.n_episodes} complete episodes (run collect again to append from there)"
        )

    def _send(self, header: dict, doing: str, arrays: Sequence[np.ndarray] = ()) -> None:
        try:
            self._proc.stdin.write(json.dumps(header).encode() + b"\n")
            for a in arrays:
                # Through PipeStream: numpy writes a real file with tofile(), which needs a seekable file.
                np.lib.format.write_array(PipeStream(self._proc.stdin), np.ascontiguousarray(a), allow_pickle=False)
            self._proc.stdin.flush()
        except (BrokenPipeError, OSError):
            raise self._died(doing) from None

    def _receive(self, doing: str) -> dict:
        line = self._proc.stdout.readline()
        if not line:
            raise self._died(doing)
        reply = json.loads(line)
        if reply.get("error") == "ValueError":  # a refused episode (wrong shape): the writer stays usable
            raise ValueError(reply["message"])
        if "error" in reply:
            self._done = True
            raise DatasetError(reply["message"])
        return reply

    def add_episode(self, *, scene: str, seed: int, source: str, **arrays: np.ndarray) -> int:
        """As :meth:`DatasetWriter.add_episode`; a dead writer is a :class:`DatasetError`."""
        if self._done:
            raise DatasetError(f"dataset {self.path}: the writer failed earlier; run collect again to append")
        doing = f"writing episode {self.n_episodes}"
        names = list(arrays)
        header = {"op": "add", "scene": str(scene), "seed": int(seed), "source": str(source), "fields": names}
        self._send(header, doing, [np.asarray(arrays[k]) for k in names])
        idx = int(self._receive(doing)["index"])
        self.n_episodes = idx + 1
        return idx

    def close(self, discard: bool = False) -> None:
        """Close the file in the child and end it (``discard`` as for :meth:`DatasetWriter.close`)."""
        if self._proc.poll() is None:
            try:
                self._send({"op": "close", "discard": bool(discard)}, "closing")
                self._proc.stdout.readline()
            except DatasetError:
                pass  # it died: the complete episodes are on disk already
        for f in (self._proc.stdin, self._proc.stdout):
            try:
                f.close()
            except OSError:
                pass
        try:
            self._proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
        self._stderr.close()

    def __enter__(self) -> WriterProcess:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        self.close(discard=exc_type is not None)


# ---------------------------------------------------------------- reading
class TrajectoryDataset:
    """Read-only view of a trajectory file; validated on open, never modified.

    Parameters
    ----------
    path : the HDF5 file.
    image_size, frame_stack : what the caller expects; a different value in the file is a
        :class:`DatasetError`.

    Attributes
    ----------
    episode_lengths : int64 (N,) steps per complete episode.
    image_size, frame_stack, env_config, kit_version, created
    """

    def __init__(self, path: str | Path, image_size: int | None = None, frame_stack: int | None = None) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise DatasetError(f"dataset {self.path}: file does not exist")
        self._h5: h5py.File | None = None
        self._pid = -1
        try:
            h5 = self._file()
            attrs = dict(h5.attrs)
            if "format_version" not in attrs or "n_episodes" not in attrs:
                raise DatasetError(
                    f"dataset {self.path}: not an omcrl trajectory file (attribute "
                    f"'format_version' or 'n_episodes' missing)"
                )
            if int(attrs["format_version"]) != FORMAT_VERSION:
                raise DatasetError(
                    f"dataset {self.path}: field 'format_version' expected {FORMAT_VERSION}, "
                    f"got {int(attrs['format_version'])}"
                )
            self.image_size = int(attrs["image_size"])
            self.frame_stack = int(attrs["frame_stack"])
            self.env_config = json.loads(attrs.get("env_config", "{}"))
            self.kit_version = str(attrs.get("kit_version", ""))
            self.created = str(attrs.get("created", ""))
            for name, want, got in (
                ("image_size", image_size, self.image_size),
                ("frame_stack", frame_stack, self.frame_stack),
            ):
                if want is not None and int(want) != got:
                    raise DatasetError(f"dataset {self.path}: field '{name}' expected {int(want)}, got {got}")
            n = int(attrs["n_episodes"])
            lengths, sources, scenes = [], [], []
            for i in range(n):
                key = episode_key(i)
                if key not in h5:
                    raise DatasetError(f"dataset {self.path}: episode '{key}' missing (n_episodes={n})")
                g = h5[key]
                steps = int(g.attrs["steps"])
                for name in FIELDS:
                    want_shape = (steps, *_expected_shape(name, self.image_size))
                    if name not in g or g[name].shape != want_shape:
                        got_shape = g[name].shape if name in g else "missing"
                        raise DatasetError(
                            f"dataset {self.path}: field '{key}/{name}' expected shape {want_shape}, got {got_shape}"
                        )
                lengths.append(steps)
                sources.append(str(g.attrs["source"]))
                scenes.append(str(g.attrs["scene"]))
        except OSError as e:  # h5py reports truncated/corrupt files as OSError, and a lock held by a writer
            self.close()
            if _locked(e):
                raise DatasetError(_LOCKED.format(path=self.path)) from None
            raise DatasetError(f"dataset {self.path}: cannot read HDF5 file, truncated or corrupt ({e})") from None
        except (KeyError, ValueError) as e:
            self.close()
            raise DatasetError(f"dataset {self.path}: malformed ({e})") from None
        except DatasetError:
            self.close()
            raise
        self.episode_lengths = np.asarray(lengths, dtype=np.int64)
        self.sources = sources
        self.scenes = scenes

    # -- file handle: reopened after fork so DataLoader workers never share one
    def _file(self) -> h5py.File:
        if self._h5 is None or self._pid != os.getpid():
            self._h5 = h5py.File(self.path, "r")
            self._pid = os.getpid()
        return self._h5

    def close(self) -> None:
        if self._h5 is not None:
            try:
                self._h5.close()
            finally:
                self._h5 = None

    def __enter__(self) -> TrajectoryDataset:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def __len__(self) -> int:
        return len(self.episode_lengths)

    @property
    def n_steps(self) -> int:
        return int(self.episode_lengths.sum())

    # -- metadata
    @property
    def fingerprint(self) -> str:
        """Short sha256 of the file attributes and episode lengths: names the data a model was trained on."""
        h5 = self._file()
        attrs = {k: (v.item() if hasattr(v, "item") else str(v)) for k, v in h5.attrs.items() if k != "created"}
        blob = json.dumps(
            {"attrs": attrs, "lengths": self.episode_lengths.tolist(), "sources": self.sources},
            sort_keys=True,
            default=str,
        )
        return hashlib.sha256(blob.encode()).hexdigest()[:12]

    def summary(self) -> dict:
        """``{"episodes", "steps", "per_source": {source: {"episodes", "steps"}}, "scenes", ...}``."""
        per: dict[str, dict[str, int]] = {}
        for src, n in zip(self.sources, self.episode_lengths):
            d = per.setdefault(src, {"episodes": 0, "steps": 0})
            d["episodes"] += 1
            d["steps"] += int(n)
        return {
            "path": str(self.path),
            "episodes": len(self),
            "steps": self.n_steps,
            "per_source": per,
            "scenes": sorted(set(self.scenes)),
            "image_size": self.image_size,
            "frame_stack": self.frame_stack,
            "fingerprint": self.fingerprint,
        }

    def episode_attrs(self, ep: int) -> dict:
        """``scene``, ``seed``, ``source``, ``steps`` of episode ``ep``."""
        g = self._group(ep)
        return {k: (v.item() if hasattr(v, "item") else v) for k, v in g.attrs.items()}

    # -- data
    def _group(self, ep: int) -> h5py.Group:
        if not 0 <= ep < len(self):
            raise IndexError(f"dataset {self.path}: episode {ep} out of range [0, {len(self)})")
        return self._file()[episode_key(ep)]

    def read(self, ep: int, name: str, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Rows ``start:stop`` of field ``name`` of episode ``ep`` (shapes in the module docstring)."""
        if name not in FIELDS:
            raise KeyError(f"unknown field {name!r}; fields are {list(FIELDS)}")
        try:
            return self._group(ep)[name][start:stop]
        except OSError as e:
            raise DatasetError(
                f"dataset {self.path}: cannot read '{episode_key(ep)}/{name}' ({' '.join(str(e).split())[:160]}); "
                "the file is damaged: collect again"
            ) from None

    def read_stacks(
        self,
        ep: int,
        ts: Sequence[int] | np.ndarray,
        frame_stack: int | None = None,
        frames: np.ndarray | None = None,
        frames_start: int = 0,
    ) -> np.ndarray:
        """Observation stacks h_t of episode ``ep`` at steps ``ts``.

        Returns uint8 (len(ts), 3L, H, W): frames t-L+1 … t, oldest first, channels frame-major (the env's
        ``obs["rgb"]`` (L, 3, H, W) reshaped); frames before the episode start repeat the first frame.
        ``frames`` (rows ``frames_start:`` of the episode's rgb) avoids a read when the caller has them.
        """
        L = int(frame_stack or self.frame_stack)
        ts = np.asarray(ts, dtype=np.int64)
        if frames is None:
            lo = max(int(ts.min()) - L + 1, 0)
            frames, frames_start = self.read(ep, "rgb", lo, int(ts.max()) + 1), lo
        idx = np.clip(ts[:, None] + np.arange(-L + 1, 1)[None, :], 0, None) - frames_start  # (n, L)
        out = frames[idx]  # (n, L, 3, H, W)
        return out.reshape(len(ts), 3 * L, *out.shape[-2:])


def open_dataset(path: str | Path, image_size: int | None = None, frame_stack: int | None = None) -> TrajectoryDataset:
    """Open and validate a trajectory file (read-only); raises :class:`DatasetError` naming the problem."""
    return TrajectoryDataset(path, image_size=image_size, frame_stack=frame_stack)


def iter_episodes(ds: TrajectoryDataset, fields: Iterable[str] = ("state", "privileged", "action")):
    """Yield ``(ep, {field: array})`` for every episode (reads one episode at a time)."""
    for ep in range(len(ds)):
        yield ep, {f: ds.read(ep, f) for f in fields}


def make_synthetic_dataset(
    path: str | Path,
    n_episodes: int = 4,
    length: int | Sequence[int] = 20,
    image_size: int = 16,
    frame_stack: int = 3,
    seed: int = 0,
    pattern: str = "moving",
) -> Path:
    """Write a small synthetic trajectory file with :class:`DatasetWriter` (tests, examples, no simulator).

    ``pattern="ids"``: every pixel of channel 0 is the episode index and of channel 1 the step (mod 256), so a
    sample's origin can be read back from its pixels. ``pattern="moving"``: a bright square drifts across a
    per-episode background; ``privileged[:3]`` is the square's offset from the image centre, so the frames
    carry information a probe can recover and neighbouring frames predict a masked one.
    """
    rng = np.random.default_rng(seed)
    lengths = [int(length)] * n_episodes if np.isscalar(length) else [int(x) for x in length]
    S = image_size
    with DatasetWriter(path, S, frame_stack, {"synthetic": pattern}) as w:
        for ep, T in enumerate(lengths):
            rgb = np.zeros((T, 3, S, S), np.uint8)
            priv = np.zeros((T, 6), np.float32)
            if pattern == "ids":
                rgb[:, 0] = ep % 256
                rgb[:, 1] = (np.arange(T) % 256)[:, None, None]
            else:
                rgb[:] = rng.integers(0, 80, size=3, dtype=np.uint8)[None, :, None, None]
                side = max(S // 4, 2)
                pos = rng.uniform(0, S - side, size=2)
                vel = rng.uniform(-1.5, 1.5, size=2)
                for t in range(T):
                    pos = pos + vel
                    for a in range(2):  # bounce off the image border
                        if not 0 <= pos[a] <= S - side:
                            vel[a] = -vel[a]
                            pos[a] = np.clip(pos[a], 0, S - side)
                    y, x = pos.astype(int)
                    rgb[t, :, y : y + side, x : x + side] = 255
                    priv[t, :2] = (pos + side / 2 - S / 2) / S
            w.add_episode(
                rgb=rgb,
                depth=rng.uniform(0.5, 5, (T, S, S)).astype(np.float32),
                state=rng.normal(size=(T, 12)).astype(np.float32),
                privileged=priv,
                action=rng.uniform(-1, 1, (T, 3)).astype(np.float32),
                reward=np.zeros(T, np.float32),
                done=np.arange(T) == T - 1,
                scene="box",
                seed=ep,
                source=SOURCES[ep % 2],
            )
    return Path(path)
