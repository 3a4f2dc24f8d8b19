"""Which episode starts meet TinyRenderer's floor-tile faults (docs/reproducibility.md, "Renderer"), by planning them
again without flying.

    python scripts/render_fault_audit.py train [--episodes 4000] [--seeds 0,1,2] [--lanes 2] [--scene box-v2]
    python scripts/render_fault_audit.py eval [--preset quick]

``train``: a training lane's starts follow from its env seed alone (``seed * 1000 + lane``, plus 100 per resume:
``omcrl.rl.train``; a run trained since 2026-12-05 lists each stretch's seed and first step in run.json's
``segments``), so the episode planner replays them; each start exactly above a tile corner is rendered once
from the pose itself, as before the fix, and reported with whether its depth held NaN. ``eval``: the Table I
evaluation starts of every scene of the preset's suite (the same for every training seed), checked the same way and
for a camera plane on box edges (``NavEnv._plane_is_clear``).
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from omcrl.config import load_config
from omcrl.envs.nav_env import NavEnv, pb
from omcrl.eval.runner import eval_seeds
from omcrl.scenes import floor_tile_m


def _raw_nan(env: NavEnv, start: np.ndarray) -> bool:
    """Whether one render from ``start`` (x m, y m, yaw rad), with no nudge, gives a NaN depth buffer."""
    env.drone = replace(env.drone, pos=np.array([start[0], start[1], env.cfg.altitude]), yaw=float(start[2]))
    S = env.cfg.image_size
    *_, zbuf, _ = pb.getCameraImage(
        S, S, env.view_matrix(), env._proj, renderer=env._pb_renderer, shadow=0,
        flags=pb.ER_NO_SEGMENTATION_MASK, physicsClientId=env._client, **env._light(),
    )  # fmt: skip
    return bool(np.isnan(np.asarray(zbuf, np.float32)).any())


def _on_corner(scene: str, xy: np.ndarray) -> bool:
    tile = floor_tile_m(scene)
    return bool(xy[0] % tile == 0.0 and xy[1] % tile == 0.0)


def audit_training(scene: str, seeds: list[int], lanes: int, episodes: int) -> None:
    cfg = load_config("quick").env
    for seed in seeds:
        for lane in range(lanes):
            env = NavEnv(scene, config=cfg)
            env.reset(seed=seed * 1000 + lane)
            corners, faulty = 0, 0
            for k in range(episodes):
                if k:  # episode 0 is the reset's own
                    plan, _ = env.episodes.begin(env.np_random, reseed=False, options={})
                    env_start, prims = plan.placed[0], plan.prims
                else:
                    env_start, prims = env.pose, None
                start = np.asarray(env_start, np.float64)
                if _on_corner(scene, start):
                    if prims is not None:
                        env._build_bodies(prims)
                    bad = _raw_nan(env, start)
                    corners, faulty = corners + 1, faulty + bad
                    print(f"seed {seed} lane {lane} episode {k}: start {np.round(start, 4).tolist()}, NaN {bad}")
            print(f"seed {seed} lane {lane}: {episodes} starts, {corners} on a corner, {faulty} with a faulty frame")
            env.close()


def audit_evaluation(preset: str) -> None:
    cfg = load_config(preset)
    for scene in cfg.eval.scenes:
        env = NavEnv(scene, config=cfg.env)
        corners = faulty = on_edges = 0
        for s in eval_seeds(cfg.eval.episodes, 0, cfg.eval.seed_offset):
            env.reset(seed=s)
            corners += _on_corner(scene, env.drone.pos[:2])
            on_edges += not env._plane_is_clear(0.0)
            faulty += _raw_nan(env, env.pose)
        print(f"{scene}: {cfg.eval.episodes} starts, {corners} on a corner, {faulty} faulty, {on_edges} on box edges")
        env.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("what", choices=("train", "eval"))
    ap.add_argument("--episodes", type=int, default=4000, help="starts replayed per training lane")
    ap.add_argument("--seeds", default="0,1,2", help="training seeds")
    ap.add_argument("--lanes", type=int, default=2, help="training lanes (rl.n_envs)")
    ap.add_argument("--scene", default="box-v2", help="training scene")
    ap.add_argument("--preset", default="quick", help="preset whose evaluation starts are checked")
    a = ap.parse_args()
    if a.what == "train":
        audit_training(a.scene, [int(s) for s in a.seeds.split(",")], a.lanes, a.episodes)
    else:
        audit_evaluation(a.preset)


if __name__ == "__main__":
    main()
