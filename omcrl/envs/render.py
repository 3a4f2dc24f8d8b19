"""Which PyBullet renderer draws the camera: TinyRenderer (CPU) or the EGL plugin (GPU, headless OpenGL).

``env.renderer``: ``tiny`` always uses TinyRenderer; ``egl`` loads PyBullet's ``eglRenderer`` plugin into the
env's client and renders with ``ER_BULLET_HARDWARE_OPENGL`` (an error naming the cause when it cannot load);
``auto`` uses EGL when a CUDA GPU is present and the plugin loads, TinyRenderer otherwise. Both give images of
``env.image_size`` px and depth converted from the same OpenGL z-buffer convention to metres; their pixels
differ (shading and rasterisation are not the same code), so the resolved renderer is part of every run's and
evaluation's identity (:func:`env_identity`).
"""

from __future__ import annotations

import functools
import warnings
from typing import Any

from omcrl.config import ConfigError, section_identity
from omcrl.utils.quiet import import_quietly

# PyBullet is imported inside the functions that render: resolving a renderer name for a run's identity needs
# none of it.

RENDERERS = ("auto", "tiny", "egl")


class RendererError(ConfigError):
    """``env.renderer='egl'`` was asked for and the EGL plugin cannot be used here."""


def _egl_plugin_file() -> str:
    import importlib.util

    spec = importlib.util.find_spec("eglRenderer")  # PyBullet ships the plugin as this extension module
    if spec is None or not spec.origin:
        raise RendererError("env.renderer='egl': PyBullet's eglRenderer plugin is not installed with pybullet")
    return spec.origin


def load_egl(client: int) -> int:
    """Load the EGL renderer plugin into ``client``; returns the plugin id, raises RendererError otherwise."""
    pb = import_quietly("pybullet")

    plugin = pb.loadPlugin(_egl_plugin_file(), "_eglRendererPlugin", physicsClientId=client)
    if plugin < 0:
        raise RendererError(
            "env.renderer='egl': PyBullet could not load its EGL renderer plugin (no EGL device; a GPU driver "
            "with EGL is needed); use env.renderer=tiny or auto"
        )
    return int(plugin)


def _cuda_present() -> bool:
    try:
        import torch

        return bool(torch.cuda.is_available())
    except Exception:  # pragma: no cover - torch is a dependency; a broken CUDA runtime means no GPU
        return False


@functools.cache
def _egl_works() -> bool:
    """Whether a fresh DIRECT client loads the EGL plugin and renders one frame (checked once per process)."""
    pb = import_quietly("pybullet")

    cid = pb.connect(pb.DIRECT)
    try:
        load_egl(cid)
        view = pb.computeViewMatrix([0, 0, 1], [1, 0, 1], [0, 0, 1])
        proj = pb.computeProjectionMatrixFOV(60, 1.0, 0.05, 20.0)
        pb.getCameraImage(8, 8, view, proj, renderer=pb.ER_BULLET_HARDWARE_OPENGL, physicsClientId=cid)
        return True
    except Exception as e:  # any failure means: fall back to TinyRenderer
        warnings.warn(f"env.renderer=auto: EGL rendering is not usable here ({e}); using TinyRenderer", stacklevel=3)
        return False
    finally:
        pb.disconnect(physicsClientId=cid)


def resolve_renderer(name: str) -> str:
    """``tiny`` or ``egl`` for an ``env.renderer`` value (``auto``: EGL only with a CUDA GPU where it works)."""
    if name not in RENDERERS:
        raise ConfigError(f"env.renderer: got {name!r}, allowed values are {list(RENDERERS)}")
    if name == "auto":
        return "egl" if _cuda_present() and _egl_works() else "tiny"
    return name


def pybullet_renderer(resolved: str) -> int:
    """The ``getCameraImage`` renderer flag for a resolved renderer name."""
    pb = import_quietly("pybullet")

    return pb.ER_BULLET_HARDWARE_OPENGL if resolved == "egl" else pb.ER_TINY_RENDERER


def env_identity(env_cfg: Any) -> dict:
    """The env section as it enters run and evaluation keys: :func:`~omcrl.config.section_identity` with the
    renderer resolved (so a run keyed on a GPU with EGL never shares a key with a TinyRenderer run)."""
    return section_identity(env_cfg, renderer=resolve_renderer(env_cfg.renderer))
