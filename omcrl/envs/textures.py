"""Procedural textures, generated at run time (no downloads) and cached as PNG files.

A texture name is ``"<kind>"`` or ``"<kind>:<variant>"``; the same name always gives the same pixels. PyBullet
loads textures from files, so each one is written once to ``$OMCRL_CACHE/textures`` (default
``~/.cache/omcrl/textures``) with an atomic rename, which is safe when several env workers start together.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path

import cv2
import numpy as np

from omcrl.utils.io import atomic_write_bytes

TEXTURE_KINDS = (
    "crate",
    "wood",
    "fabric",
    "metal",
    "marble",
    "brick",
    "concrete",
    "bark",
    "leaves",
    "grass",
    "tiles",
    "carpet",
    "paint",
    "sky",
    "checker",
    "stripes",
)
_SIZE = 64
_VERSION = "v1"


def cache_dir() -> Path:
    """The texture cache folder, created if needed: ``$OMCRL_CACHE/textures/v1``, else
    ``~/.cache/omcrl/textures/v1``, else (no usable home) ``<tmp>/omcrl-cache-<uid>/textures/v1``.

    An ``OMCRL_CACHE`` that is not a usable folder is an error naming the variable; an unusable default falls
    back to the temporary folder (the textures are regenerated on demand, so nothing is lost).
    """
    env = os.environ.get("OMCRL_CACHE")
    if env:
        d = Path(env) / "textures" / _VERSION
        try:
            d.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise NotADirectoryError(
                f"OMCRL_CACHE={env!r} cannot hold the texture cache ({e.strerror}); point it at a writable folder "
                "or unset it"
            ) from None
        return d
    for root in (Path.home() / ".cache" / "omcrl", Path(tempfile.gettempdir()) / f"omcrl-cache-{os.getuid()}"):
        d = root / "textures" / _VERSION
        try:
            d.mkdir(parents=True, exist_ok=True)
        except OSError:
            continue
        if os.access(d, os.W_OK):
            return d
    raise NotADirectoryError("no writable folder for the texture cache: set OMCRL_CACHE to one")


def _rng(name: str) -> np.random.Generator:
    return np.random.default_rng(int.from_bytes(hashlib.sha256(name.encode()).digest()[:8], "little"))


def _noise(rng: np.random.Generator, n: int, scale: int) -> np.ndarray:
    """Smooth value noise in [0, 1], (n, n): random grid at ``n/scale`` resolution, bicubic upsampled."""
    k = max(2, n // scale)
    small = rng.random((k, k)).astype(np.float32)
    return np.clip(cv2.resize(small, (n, n), interpolation=cv2.INTER_CUBIC), 0, 1)


def _palette(rng: np.random.Generator, base: tuple[float, float, float], jitter: float) -> np.ndarray:
    return np.clip(np.asarray(base, np.float32) + rng.uniform(-jitter, jitter, 3), 0, 1)


def make_texture(name: str, size: int = _SIZE) -> np.ndarray:
    """Pixels of texture ``name`` as uint8 RGB, shape (size, size, 3)."""
    kind = name.split(":")[0]
    if kind not in TEXTURE_KINDS:
        raise ValueError(f"texture {name!r}: unknown kind {kind!r}, expected one of {TEXTURE_KINDS}")
    rng = _rng(name)
    n = size
    yy, xx = np.mgrid[0:n, 0:n].astype(np.float32) / n
    fine = _noise(rng, n, 4)
    coarse = _noise(rng, n, 16)
    if kind == "crate":
        col = _palette(rng, (0.62, 0.45, 0.25), 0.04)
        img = col * (0.85 + 0.15 * fine[..., None])
        band = (np.abs(xx - 0.5) < 0.06) | (np.abs(yy - 0.5) < 0.06)
        img[band] = _palette(rng, (0.78, 0.68, 0.45), 0.03)
        edge = (xx < 0.04) | (xx > 0.96) | (yy < 0.04) | (yy > 0.96)
        img[edge] *= 0.6
    elif kind == "wood":
        col = _palette(rng, (0.55, 0.36, 0.2), 0.12)
        rings = 0.5 + 0.5 * np.sin((xx * 18 + 4 * coarse) * np.pi)
        img = col * (0.7 + 0.3 * rings[..., None])
    elif kind == "fabric":
        col = _palette(rng, tuple(rng.uniform(0.2, 0.8, 3)), 0.0)
        weave = 0.5 + 0.25 * (np.sin(xx * n * np.pi) + np.sin(yy * n * np.pi))
        img = col * (0.75 + 0.25 * weave[..., None] * fine[..., None])
    elif kind == "metal":
        col = _palette(rng, (0.6, 0.62, 0.65), 0.1)
        streak = _noise(rng, n, 2)[:, :1].repeat(n, 1)
        img = col * (0.75 + 0.25 * streak[..., None])
    elif kind == "marble":
        col = _palette(rng, (0.88, 0.87, 0.85), 0.05)
        vein = np.abs(np.sin((xx + yy + 2 * coarse) * 6 * np.pi)) ** 8
        img = col * (1.0 - 0.4 * vein[..., None])
    elif kind == "brick":
        col = _palette(rng, (0.6, 0.25, 0.18), 0.08)
        row = np.floor(yy * 8)
        shift = (row % 2) * 0.125
        mortar = ((yy * 8) % 1 < 0.12) | (((xx + shift) * 4) % 1 < 0.06)
        img = col * (0.8 + 0.2 * fine[..., None])
        img[mortar] = (0.75, 0.73, 0.7)
    elif kind == "concrete":
        col = _palette(rng, (0.55, 0.55, 0.53), 0.08)
        img = col * (0.75 + 0.25 * (0.6 * fine + 0.4 * coarse)[..., None])
    elif kind == "bark":
        col = _palette(rng, (0.35, 0.24, 0.15), 0.08)
        grooves = 0.5 + 0.5 * np.sin((xx * 14 + 2 * coarse) * np.pi)
        img = col * (0.55 + 0.45 * (grooves * fine)[..., None])
    elif kind == "leaves":
        col = _palette(rng, (0.2, 0.5, 0.18), 0.12)
        blotch = _noise(rng, n, 8)
        img = col * (0.5 + 0.6 * blotch[..., None])
    elif kind == "grass":
        col = _palette(rng, (0.3, 0.55, 0.2), 0.06)
        blades = _noise(rng, n, 2)
        img = col * (0.6 + 0.4 * blades[..., None])
    elif kind == "tiles":
        col = _palette(rng, (0.8, 0.78, 0.72), 0.1)
        grout = ((xx * 4) % 1 < 0.05) | ((yy * 4) % 1 < 0.05)
        img = col * (0.9 + 0.1 * fine[..., None])
        img[grout] *= 0.55
    elif kind == "carpet":
        col = _palette(rng, tuple(rng.uniform(0.25, 0.6, 3)), 0.0)
        img = col * (0.8 + 0.2 * fine[..., None])
    elif kind == "paint":
        col = _palette(rng, (0.85, 0.83, 0.78), 0.08)
        img = col * (0.95 + 0.05 * coarse[..., None])
    elif kind == "sky":
        top = np.array([0.35, 0.55, 0.9], np.float32)
        bottom = np.array([0.8, 0.88, 0.97], np.float32)
        clouds = np.clip(_noise(rng, n, 12) * 1.6 - 0.8, 0, 1)
        img = top * (1 - yy[..., None]) + bottom * yy[..., None]
        img = img * (1 - clouds[..., None]) + clouds[..., None]
    elif kind == "checker":
        a, b = _palette(rng, (0.8, 0.2, 0.2), 0.2), _palette(rng, (0.2, 0.2, 0.8), 0.2)
        chk = ((np.floor(xx * 4) + np.floor(yy * 4)) % 2)[..., None]
        img = a * chk + b * (1 - chk)
    else:  # stripes
        a, b = _palette(rng, (0.9, 0.8, 0.1), 0.1), _palette(rng, (0.1, 0.1, 0.1), 0.05)
        st = (((xx + yy) * 6) % 1 < 0.5)[..., None]
        img = a * st + b * (1 - st)
    return (np.clip(img, 0, 1) * 255).astype(np.uint8)


def texture_file(name: str) -> str:
    """Path of the cached PNG for ``name``, generating it on first use."""
    d = cache_dir()
    safe = name.replace(":", "_")
    path = d / f"{safe}.png"
    if not path.exists():
        ok, buf = cv2.imencode(".png", cv2.cvtColor(make_texture(name), cv2.COLOR_RGB2BGR))
        if not ok:  # pragma: no cover - cv2 always encodes uint8 RGB
            raise RuntimeError(f"could not encode texture {name!r}")
        atomic_write_bytes(path, buf.tobytes())
    return str(path)
