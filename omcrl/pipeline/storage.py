"""Storage that sweep jobs share when the nodes of a Ray cluster do not share a filesystem.

A job on a node works in that node's own project root (``OMCRL_ROOT``, else the checkout, else
``~/.cache/omcrl``), as a cache. Before it starts it *pulls* what its dependencies produced (and its own outputs,
when an earlier sweep finished it, so the run registry skips it); after it finishes it *pushes* its outputs and its
log. The location is ``sweep.storage``: a folder every node can reach (NFS, a mounted bucket) or any URI a
maintained filesystem layer understands (``fsspec``: ``s3://``, ``gs://``, ``file://``, ...), as Ray Train's
``storage_path`` is.

Layout under the storage root::

    blobs/<sha256[:2]>/<sha256>     file contents, content-addressed: concurrent pushes never clash
    manifests/<job key>.json        what a job produced: {relative path: {"sha256", "bytes"}}
    logs/<grid>/<job log name>      each job's log
    checks/<marker>                 the driver's reachability marker

Paths in a manifest are relative to the project root of the node that pushed them (an absolute path outside it
is kept absolute), so two nodes with different roots exchange the same files. Every pulled file is checked
against its manifest's SHA-256 before it replaces anything; a blob that does not match is refused, naming it.
"""

from __future__ import annotations

import hashlib
import json
import os
import uuid
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from omcrl.config import project_root

FORMAT = 1
SKIP_NAMES = (".tmp", ".lock")  # atomic-write temporaries and registry locks are never shared


class StorageError(RuntimeError):
    """Sweep storage cannot be reached, or holds something that fails its check; the message names it."""


def sha256(path: str | Path) -> str:
    """Hex SHA-256 of a file's content."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def job_key(job_id: str, root: str | Path | None = None) -> str:
    """A storage name for a job: its id with the driver's project root taken out, hashed (ids hold paths)."""
    text = job_id.replace(str(root or project_root()), "<root>")
    return hashlib.sha256(text.encode()).hexdigest()[:24]


def shareable(path: Path) -> bool:
    """Whether a file is an artifact to share (not a temporary of an atomic write, not a lock)."""
    return path.is_file() and not path.name.startswith(".") and not path.name.endswith(SKIP_NAMES)


def files_under(paths: Iterable[str | Path]) -> list[Path]:
    """Every shareable file of ``paths`` (a file itself, a folder recursively), sorted; missing ones left out."""
    out: set[Path] = set()
    for p in map(Path, paths):
        if p.is_dir():
            out.update(f for f in p.rglob("*") if shareable(f))
        elif shareable(p):
            out.add(p)
    return sorted(out)


class Storage:
    """One sweep storage location (``sweep.storage``), through ``fsspec``.

    Parameters
    ----------
    uri : a folder path or a URI (``s3://bucket/prefix``, ``file:///shared/omcrl``, ...).
    """

    def __init__(self, uri: str) -> None:
        import fsspec

        if not str(uri).strip():
            raise StorageError("sweep.storage: got '', expected a folder or a URI every node can reach")
        self.uri = str(uri)
        try:
            self.fs, self.root = fsspec.core.url_to_fs(self.uri)
        except (ImportError, ValueError) as e:
            raise StorageError(f"sweep.storage {self.uri!r}: fsspec cannot open it ({e})") from None
        self.root = self.root.rstrip("/")

    def __repr__(self) -> str:
        return f"Storage({self.uri!r})"

    # -- paths -------------------------------------------------------------------------------------------------
    def _at(self, *parts: str) -> str:
        return "/".join([self.root, *parts])

    def _blob(self, digest: str) -> str:
        return self._at("blobs", digest[:2], digest)

    def _manifest(self, key: str) -> str:
        return self._at("manifests", f"{key}.json")

    @staticmethod
    def _rel(path: Path, base: Path) -> str:
        path = path.absolute()
        try:
            return path.relative_to(base).as_posix()
        except ValueError:
            return path.as_posix()  # outside the project root (an absolute data.file): kept as it is

    @staticmethod
    def _local(rel: str, base: Path) -> Path:
        p = Path(rel)
        if not p.is_absolute() and ".." in p.parts:
            raise StorageError(f"sweep storage: manifest path {rel!r} leaves the project root; refusing it")
        return p if p.is_absolute() else base / p

    def _put(self, local: Path, remote: str) -> None:
        # Upload under a unique name, then move: a reader never sees half a file.
        part = f"{remote}.part-{uuid.uuid4().hex[:8]}"
        self.fs.makedirs(remote.rsplit("/", 1)[0], exist_ok=True)
        self.fs.put_file(str(local), part)
        self.fs.mv(part, remote)

    def _write_text(self, remote: str, text: str) -> None:
        part = f"{remote}.part-{uuid.uuid4().hex[:8]}"
        self.fs.makedirs(remote.rsplit("/", 1)[0], exist_ok=True)
        with self.fs.open(part, "w", encoding="utf-8") as f:
            f.write(text)
        self.fs.mv(part, remote)

    # -- manifests ---------------------------------------------------------------------------------------------
    def push(self, key: str, paths: Iterable[str | Path], base: Path | None = None) -> dict[str, Any]:
        """Upload the shareable files of ``paths`` (blobs not yet stored) and write job ``key``'s manifest.

        Returns the manifest ``{"format", "files": {relative path: {"sha256", "bytes"}}}``.
        """
        base = (base or project_root()).absolute()
        files: dict[str, dict[str, Any]] = {}
        for f in files_under(paths):
            digest = sha256(f)
            if not self.fs.exists(self._blob(digest)):
                self._put(f, self._blob(digest))
            files[self._rel(f, base)] = {"sha256": digest, "bytes": f.stat().st_size}
        manifest = {"format": FORMAT, "files": files}
        self._write_text(self._manifest(key), json.dumps(manifest, indent=1, sort_keys=True))
        return manifest

    def manifest(self, key: str) -> dict[str, Any] | None:
        """Job ``key``'s manifest, or None when that job never pushed; a damaged one raises, naming it."""
        path = self._manifest(key)
        if not self.fs.exists(path):
            return None
        try:
            with self.fs.open(path, "r", encoding="utf-8") as f:
                m = json.load(f)
            if m.get("format") != FORMAT or not isinstance(m.get("files"), dict):
                raise ValueError(f"expected format {FORMAT} with a 'files' object")
            for rel, e in m["files"].items():
                if not (isinstance(rel, str) and isinstance(e.get("sha256"), str) and len(e["sha256"]) == 64):
                    raise ValueError(f"entry {rel!r}: expected a 64-digit sha256")
        except (ValueError, AttributeError, TypeError) as e:
            raise StorageError(
                f"sweep storage: manifest {self.uri}/manifests/{key}.json is damaged ({e}); delete it and re-run "
                "the sweep (its job runs again)"
            ) from None
        return m

    def pull(self, keys: Iterable[str], base: Path | None = None) -> dict[str, int]:
        """Fetch the files of jobs ``keys``' manifests into ``base`` (default: this node's project root).

        A local file with the manifest's digest is kept; a missing or different one is replaced by the stored
        blob after its SHA-256 is checked. Returns ``{"fetched", "kept", "missing_manifests"}``.
        """
        base = (base or project_root()).absolute()
        stats = {"fetched": 0, "kept": 0, "missing_manifests": 0}
        for key in keys:
            m = self.manifest(key)
            if m is None:
                stats["missing_manifests"] += 1
                continue
            for rel, e in sorted(m["files"].items()):
                local = self._local(rel, base)
                if local.is_file() and sha256(local) == e["sha256"]:
                    stats["kept"] += 1
                    continue
                self._fetch(e["sha256"], local)
                stats["fetched"] += 1
        return stats

    def _fetch(self, digest: str, local: Path) -> None:
        blob = self._blob(digest)
        if not self.fs.exists(blob):
            raise StorageError(f"sweep storage: blob {self.uri}/blobs/{digest[:2]}/{digest} for {local} is missing")
        local.parent.mkdir(parents=True, exist_ok=True)
        tmp = local.with_name(f".{local.name}.{uuid.uuid4().hex[:8]}.tmp")
        try:
            self.fs.get_file(blob, str(tmp))
            got = sha256(tmp)
            if got != digest:
                raise StorageError(
                    f"sweep storage: blob {self.uri}/blobs/{digest[:2]}/{digest} has sha256 {got[:12]}…, not "
                    f"{digest[:12]}… (damaged in storage); delete it and re-run the job that made {local.name}"
                )
            os.replace(tmp, local)
        finally:
            tmp.unlink(missing_ok=True)

    # -- logs and checks ---------------------------------------------------------------------------------------
    def push_log(self, grid: str, name: str, local: Path) -> None:
        """Store a job's log (replacing an earlier attempt's)."""
        if local.is_file():
            self._put(local, self._at("logs", grid, name))

    def fetch_log(self, grid: str, name: str, local: Path) -> bool:
        """Copy a job's stored log to ``local`` (the driver's log path); False when there is none."""
        remote = self._at("logs", grid, name)
        if not self.fs.exists(remote):
            return False
        local.parent.mkdir(parents=True, exist_ok=True)
        self.fs.get_file(remote, str(local))
        return True

    def write_marker(self) -> str:
        """Write a reachability marker; returns its name (see :meth:`has_marker`)."""
        name = f"marker-{uuid.uuid4().hex[:12]}"
        try:
            self._write_text(self._at("checks", name), "written by the sweep's driver\n")
        except OSError as e:
            raise StorageError(f"sweep.storage {self.uri}: the driver cannot write there ({e})") from None
        return name

    def has_marker(self, name: str) -> bool:
        return bool(self.fs.exists(self._at("checks", name)))

    def remove_marker(self, name: str) -> None:
        if self.fs.exists(self._at("checks", name)):
            self.fs.rm(self._at("checks", name))
