"""Atomic writes: a file is either the old complete version or the new complete version, never half."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a temporary file in the same folder and ``os.replace``."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=p.parent, prefix=f".{p.name}.", suffix=".tmp")
    try:
        # mkstemp creates 0600; a finished artifact gets the permissions the user's umask gives any new file.
        os.fchmod(fd, 0o666 & ~current_umask())
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def current_umask() -> int:
    """The process umask (read by setting and restoring it)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def atomic_write_text(path: str | Path, text: str) -> None:
    """Text version of :func:`atomic_write_bytes` (UTF-8)."""
    atomic_write_bytes(path, text.encode("utf-8"))


def atomic_save_torch(obj: Any, path: str | Path, before_replace: Any = None) -> str:
    """``torch.save`` to a temporary file, then rename: an interrupted save never corrupts ``path``.

    Returns the content's digest (:func:`file_digest` of the file written). ``before_replace(digest)``, when
    given, runs before the file appears (a producer records the digest first, so a kill between the two never
    leaves a file whose digest is not on record).
    """
    import io

    import torch

    buf = io.BytesIO()
    torch.save(obj, buf)
    data = buf.getvalue()
    digest = bytes_digest(data)
    if before_replace is not None:
        before_replace(digest)
    atomic_write_bytes(path, data)
    return digest


def bytes_digest(data: bytes, length: int = 16) -> str:
    """Hex SHA-1 prefix of ``data``: what :func:`file_digest` gives for a file holding it."""
    import hashlib

    return hashlib.sha1(data).hexdigest()[:length]


def file_digest(path: str | Path, length: int = 16) -> str:
    """Hex SHA-1 prefix of a file's content ("" when it does not exist): identifies checkpoints in cache keys."""
    import hashlib

    p = Path(path)
    if not p.is_file():
        return ""
    h = hashlib.sha1()
    with open(p, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()[:length]


class UnsafeFileError(RuntimeError):
    """A torch file cannot be read as tensors and plain containers (corrupt, or it holds other objects)."""


def load_torch(path: str | Path, what: str = "checkpoint", error: type[Exception] = UnsafeFileError) -> Any:
    """``torch.load`` with ``weights_only=True``; every failure raises ``error`` naming the file.

    The kit never unpickles arbitrary objects from a file a user can be handed: a file that needs more than
    tensors and plain containers is refused, and the message does not suggest turning that protection off.
    """
    import torch

    p = Path(path)
    if not p.is_file():
        raise error(f"{what} {p} does not exist")
    try:
        return torch.load(p, map_location="cpu", weights_only=True)
    except Exception as e:
        kind = type(e).__name__
        why = (
            "it holds objects other than tensors and plain containers, which the kit refuses to unpickle"
            if "Unpickl" in kind or "weights_only" in str(e)
            else "it is truncated or not a torch file"
        )
        raise error(f"{what} {p}: not a readable {what}: {why} ({kind}); delete it or restore a good copy") from None
