"""Frames that cost what they show (issue: speed, third pass, item 1): TinyRenderer draws only the bodies a frame can
show, and every frame stays bit-identical to the frames rendered before culling existed.

``FLIGHT_PINS`` were written by :func:`flight_digest` on main at 13a6b78, before culling (the env then drew every
body, the parked ones too). Regenerate only for a deliberate change of the frames:
``python -m tests.test_render_cull --write``.
"""

from __future__ import annotations

import hashlib
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from omcrl.envs import make_env
from omcrl.envs.appearance import CullSet, bounding_radius
from omcrl.scenes import SCENE_SPECS
from omcrl.scenes.geometry import Primitive

PINS_FILE = Path(__file__).parent / "data" / "render_flight_pins.json"
# Looks that repaint bodies (a swapped look, random looks per layout: the decor is repainted on every layout, so a
# culled body must come back with its new colour) besides each scene's own.
LOOKS = {
    "own": None,
    "box-look": {"appearance": "box-v2"},
    "randomized": {"randomize_look": True, "seed": 3},
}


def _walk(n: int, seed: int) -> np.ndarray:
    """(n, 3) smooth random actions: turns and sweeps, so bodies enter and leave the view."""
    rng = np.random.default_rng(seed)
    a = np.zeros((n, 3), np.float32)
    for i in range(1, n):
        a[i] = np.clip(0.9 * a[i - 1] + 0.35 * rng.normal(size=3), -1, 1)
    a[:, 0] = np.abs(a[:, 0]) * 0.7
    return a


def flight_digest(scene: str, look: str, steps: int = 160, **env_kwargs) -> str:
    """SHA-256 (16 hex) of every RGB and depth frame (exact bytes, 40 px) of a flight of ``steps`` steps in
    ``scene`` with look ``look`` (a key of :data:`LOOKS`), over several layouts (each episode ends early every
    40 steps with a reset to the next layout seed, which moves, parks and recreates pooled bodies)."""
    env = make_env(scene, seed=11, image_size=40, disturbance=LOOKS[look], **env_kwargs)
    h = hashlib.sha256()
    try:
        obs, _ = env.reset(seed=100)
        for k, a in enumerate(_walk(steps, 5)):
            h.update(obs["rgb"].tobytes())
            h.update(obs["depth"].tobytes())
            obs, _, term, trunc, _ = env.step(a)
            if term or trunc or k % 40 == 39:
                obs, _ = env.reset(seed=101 + k // 40)
        h.update(obs["rgb"].tobytes())
        h.update(obs["depth"].tobytes())
    finally:
        env.close()
    return h.hexdigest()[:16]


FLIGHT_PINS = json.loads(PINS_FILE.read_text()) if PINS_FILE.exists() else {}
CASES = [f"{scene}/{look}" for scene in sorted(SCENE_SPECS) for look in LOOKS]


def test_every_scene_and_look_is_pinned():
    assert sorted(FLIGHT_PINS) == sorted(CASES)


@pytest.mark.parametrize("case", CASES)
def test_culled_frames_are_the_frames_before_culling(case):
    """Every frame of a flight over several layouts, in every registered scene (v0, v1, v2) and look, equals the
    frame rendered by the code before culling, byte for byte (RGB and depth)."""
    scene, look = case.split("/")
    assert flight_digest(scene, look, renderer="tiny", cull=True) == FLIGHT_PINS[case]


def test_culling_leaves_bodies_out_and_brings_them_back():
    """The culled env hides bodies (else the frame test above proves nothing) and draws each again with its own
    colour once it can be seen (a full turn in place sees every direction)."""
    env = make_env("tree-v2", seed=0, image_size=40, renderer="tiny")
    env.reset(seed=0)
    counts = []
    for _ in range(45):  # 45 steps at the full yaw rate: more than a full turn
        env.step(np.array([0.0, 0.0, 1.0], np.float32))
        counts.append(len(env._hidden))
    assert min(counts) > 10  # many of tree-v2's bodies are off-camera in any direction
    seen = set()
    for _ in range(45):
        env.step(np.array([0.0, 0.0, 1.0], np.float32))
        seen |= {int(b) for b, s in zip(env._cull_set.ids, env._cull_set.state) if s}
    assert set(env._cull_set.ids.tolist()) - seen == set()  # ... yet every body was drawn in some direction
    env.close()


def test_an_env_without_culling_hides_nothing():
    env = make_env("tree-v2", seed=0, image_size=40, renderer="tiny", cull=False)
    env.reset(seed=0)
    for _ in range(10):
        env.step(np.array([0.2, 0.0, 1.0], np.float32))
    assert env._hidden == set() and not env.cull
    env.close()


def _one(center, kind="box", size=(0.5, 0.5, 0.5)) -> CullSet:
    p = Primitive(kind, center, size)
    return CullSet.of([7], [p], set())


@pytest.mark.parametrize(
    ("center", "drawn"),
    [
        ((5.0, 0.0, 1.0), True),  # straight ahead
        ((-5.0, 0.0, 1.0), False),  # wholly behind the camera plane
        ((0.3, 4.0, 1.0), True),  # straddles the camera plane (beside the eye): always drawn
        ((2.0, 9.0, 1.0), False),  # in front, far beyond the left edge of an 82.6° view
        ((5.0, 4.0, 1.0), True),  # in front, near the left edge: its sphere crosses the side plane
        ((5.0, 0.0, 12.0), False),  # in front, far above the top edge
    ],
)
def test_cull_set_keeps_what_the_view_can_reach(center, drawn):
    """The eye at (0, 0, 1) m looking along +x, a 0.5 m cube (radius √0.75·1.05 + 0.02 m)."""
    t = math.tan(math.radians(82.6) / 2)
    cs = _one(center)
    assert bool(cs.drawn(np.array([0.0, 0.0, 1.0]), 0.0, t, t, 40, 40)[0]) is drawn


def test_bounding_radius_holds_each_kind():
    assert bounding_radius(Primitive("box", (0, 0, 0), (3.0, 4.0, 12.0))) >= 13.0
    assert bounding_radius(Primitive("cylinder", (0, 0, 0), (0.3, 0.3, 0.4))) >= 0.5
    assert bounding_radius(Primitive("sphere", (0, 0, 0), (2.0, 2.0, 2.0))) >= 2.0


if __name__ == "__main__":  # python -m tests.test_render_cull --write
    if "--write" not in sys.argv:
        sys.exit("usage: python -m tests.test_render_cull --write  (rewrites the pins: only for a deliberate change)")
    kw = {"renderer": "tiny"}
    pins = {c: flight_digest(*c.split("/"), **kw) for c in CASES}
    PINS_FILE.write_text(json.dumps(pins, indent=1, sort_keys=True) + "\n")
    print(f"wrote {len(pins)} pins to {PINS_FILE}")
