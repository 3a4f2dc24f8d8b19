"""Files released from the checkout to git history: a pointer in the file's place names the git blob that holds it.

``reference/`` travels with every clone and must stay under 60 MB; large files that a later run may still need (a
teacher's weights, an older reference bundle's archive) leave the checkout once they are committed. In a file's
place stays ``<name>.git.json``::

    {"git_blob": "<40 hex digits: the id git gives the file>", "digest": "<bytes_digest>", "bytes": <size>}

and :func:`read_kept` gives the bytes back from the repository's objects (``git cat-file``), checked against the
blob id. A shallow clone, or a copy without ``.git``, lacks them: the caller is told (None, with a warning naming
the blob) and decides what to do instead (train the teacher again, say which bundle cannot be read).
"""

from __future__ import annotations

import hashlib
import json
import subprocess
import warnings
from pathlib import Path

from omcrl.runs import CorruptFile
from omcrl.utils.io import atomic_write_text, bytes_digest

POINTER = ".git.json"


def git_blob_id(data: bytes) -> str:
    """The id git gives a file of content ``data`` (``git hash-object``): SHA-1 of ``blob <size>\\0`` + content."""
    return hashlib.sha1(b"blob %d\0" % len(data) + data).hexdigest()


def pointer_path(path: str | Path) -> Path:
    """``<path>.git.json``: where a released ``path`` points to its git blob."""
    p = Path(path)
    return p.with_name(p.name + POINTER)


def _git(where: Path, *args: str) -> subprocess.CompletedProcess | None:
    """``git -C <where> <args>`` (output as bytes), or None when git or the folder is missing."""
    try:
        return subprocess.run(["git", "-C", str(where), *args], capture_output=True, check=False)
    except OSError:
        return None


def committed(where: str | Path, blob: str) -> bool:
    """Is blob ``blob`` part of a commit of the repository holding ``where`` (any branch)?"""
    r = _git(Path(where), "log", "--all", "--format=%H", "-1", f"--find-object={blob}")
    return r is not None and r.returncode == 0 and bool(r.stdout.strip())


def read_pointer(path: str | Path, remedy: str) -> dict | None:
    """The pointer of a released ``path`` (``{"git_blob", "digest", "bytes"}``), or None when there is none.

    Raises :class:`omcrl.runs.CorruptFile` naming the pointer and ``remedy`` when it cannot be read.
    """
    p = pointer_path(path)
    if not p.is_file():
        return None
    try:
        rec = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        raise CorruptFile(f"{p} is not a readable git pointer ({e}); {remedy}") from None
    if not isinstance(rec, dict) or not isinstance(rec.get("git_blob"), str):
        raise CorruptFile(f"{p}: expected an object with a 'git_blob' field; {remedy}")
    return rec


def available(path: str | Path, remedy: str) -> bool:
    """True when ``path`` is in the checkout, or released and its blob is in the repository's objects."""
    p = Path(path)
    if p.is_file():
        return True
    rec = read_pointer(p, remedy)
    r = _git(p.parent, "cat-file", "-e", rec["git_blob"]) if rec else None
    return r is not None and r.returncode == 0


def read_kept(path: str | Path, remedy: str, unavailable: str | None = None) -> bytes | None:
    """The bytes of ``path``: the file in the checkout, or the git blob its pointer names.

    None when it is neither there nor released, and None with a warning naming the blob (ending in ``unavailable``,
    default ``remedy``) when the blob is not in this repository (a shallow clone, git missing). Raises
    :class:`omcrl.runs.CorruptFile` (ending in ``remedy``) when git returns other bytes than the blob's, or the
    pointer cannot be read.
    """
    p = Path(path)
    if p.is_file():
        return p.read_bytes()
    rec = read_pointer(p, remedy)
    if rec is None:
        return None
    blob = rec["git_blob"]
    r = _git(p.parent, "cat-file", "blob", blob)
    if r is None or r.returncode != 0:
        warnings.warn(
            f"{pointer_path(p)}: git blob {blob} is not in this repository (a shallow clone, or git missing); "
            f"{unavailable or remedy}",
            stacklevel=2,
        )
        return None
    if git_blob_id(r.stdout) != blob:
        raise CorruptFile(f"{pointer_path(p)}: git returned other bytes than blob {blob}; {remedy}")
    return r.stdout


def release(path: str | Path, data: bytes | None = None) -> Path | None:
    """Take ``path`` out of the checkout, leaving its pointer (git blob, digest, size); returns the pointer written.

    ``data``: the file's bytes when the caller has read and checked them already. Nothing happens (None) when the
    file is not there, or not yet in a commit: the pointer must name a blob that git history keeps, so a file is
    released only after it was committed.
    """
    p = Path(path)
    if not p.is_file():
        return None
    data = p.read_bytes() if data is None else data
    blob = git_blob_id(data)
    if not committed(p.parent, blob):
        return None
    pointer = pointer_path(p)
    atomic_write_text(
        pointer, json.dumps({"git_blob": blob, "digest": bytes_digest(data), "bytes": len(data)}, indent=1) + "\n"
    )
    p.unlink()
    return pointer
