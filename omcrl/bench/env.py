"""``python -m omcrl.bench env``: render and env-step throughput.

For each image size (64 and 128 px) and scene it measures, on the same scene and camera:

* ``raw_fps`` — bare ``getCameraImage`` calls (TinyRenderer, no shadows, no segmentation) replaying the camera
  poses the env visited, so raw and env renders see the same views;
* ``step_sps`` — ``NavEnv.step`` with one process, episode resets excluded from the clock;
* ``step_sps_with_resets`` — the same with resets (new layouts) included, what training sees;
* ``vec2_sps`` — a 2-env ``make_vec_env`` (env 0 in this process, one worker; resets included), total env
  steps per second;
* ``gym_async2_sps`` — the same two envs in Gymnasium's ``AsyncVectorEnv(shared_memory=True)`` (both envs in
  worker processes, observations through shared memory), for the comparison the kit's vector env must win;

and the two ratios the kit is held to: ``step/raw`` (target >= 0.8 at 64 px) and ``vec2/single`` (>= 1.6,
both with resets included), plus ``gym_async2/single`` and ``vec2/gym_async2`` (> 1: the kit's vector env is
faster than Gymnasium's). Actions are a slow random walk so episodes last long enough to be typical.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import gymnasium as gym
import numpy as np

from omcrl.bench import parser, write_results
from omcrl.envs import make_env, make_vec_env
from omcrl.envs.vec import env_factory
from omcrl.utils.quiet import import_quietly

pb = import_quietly("pybullet")


def _walk(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 3) smooth random actions in [-1, 1]."""
    a = np.zeros((n, 3))
    for i in range(1, n):
        a[i] = np.clip(0.9 * a[i - 1] + 0.3 * rng.normal(size=3), -1, 1)
    a[:, 0] = np.abs(a[:, 0]) * 0.6
    return a.astype(np.float32)


def measure(
    scene: str,
    size: int,
    seconds: float,
    n_vec: int = 2,
    block: float = 1.0,
    renderer: str = "auto",
    cull: bool = True,
) -> dict:
    """Throughputs for one scene, image size and ``env.renderer`` (``tiny``, ``egl`` or ``auto``); ``cull=False``
    draws every body for every frame (TinyRenderer before :class:`~omcrl.envs.appearance.CullSet`).

    Raw renders, single-env steps and vector-env steps run in alternating short blocks (``block`` s each) for
    ``seconds`` s in all, and each rate is the median over its blocks: whatever else the machine is doing
    then weighs on all three alike, so the ratios stay meaningful on a busy machine. Raw renders use the env's
    own renderer (TinyRenderer, or the EGL plugin it loaded), so ``step/raw`` is the env's overhead on either.
    """
    env = make_env(scene, seed=0, image_size=size, renderer=renderer, cull=cull)
    env.reset(seed=0)
    vec = make_vec_env(scene, n_vec, seed=0, image_size=size, renderer=renderer, cull=cull)
    vec.reset(seed=0)
    kwargs = {"image_size": size, "renderer": renderer, "cull": cull}
    gvec = gym.vector.AsyncVectorEnv([env_factory(scene, i, kwargs) for i in range(n_vec)], shared_memory=True)
    gvec.reset(seed=0)
    acts = _walk(np.random.default_rng(0), 100_000)
    va = np.stack([acts] * n_vec, 1)
    state = {"k": 0, "v": 0, "reset": 0.0, "step": 0.0}

    views: list = []  # camera poses the env visited, so raw renders replay the very same views

    def raw_rate() -> float:
        cid, proj = env._client, env._proj
        if not views:
            views.append((env.drone, env.view_matrix()))
        n, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < block:
            drone, view = views[n % len(views)]
            if env.cull:  # the env's culling is part of its frame's cost
                env.drone = drone
                env._cull_to(drone.pos, drone.yaw, 1.0 / proj[0], 1.0 / proj[5], size, size)
            pb.getCameraImage(
                size,
                size,
                view,
                proj,
                renderer=env._pb_renderer,
                shadow=0,
                flags=pb.ER_NO_SEGMENTATION_MASK,
                physicsClientId=cid,
            )
            n += 1
        return n / (time.perf_counter() - t0)

    def step_rates() -> tuple[float, float]:
        """(steps/s excluding resets, steps/s including resets) over one block."""
        n, t_step, t_reset, t0 = 0, 0.0, 0.0, time.perf_counter()
        while time.perf_counter() - t0 < block:
            t1 = time.perf_counter()
            _, _, term, trunc, _ = env.step(acts[state["k"] % len(acts)])
            t_step += time.perf_counter() - t1
            if len(views) < 2000:
                views.append((env.drone, env.view_matrix()))
            state["k"] += 1
            n += 1
            if term or trunc:
                t1 = time.perf_counter()
                env.reset()
                t_reset += time.perf_counter() - t1
        state["reset"] += t_reset
        state["step"] += t_step
        return n / t_step, n / (t_step + t_reset)

    def vec_rate(v: gym.vector.VectorEnv = vec) -> float:
        n, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < block:
            v.step(va[state["v"] % len(va)])
            state["v"] += 1
            n += 1
        return n * n_vec / (time.perf_counter() - t0)

    for _ in range(3):  # warm-up: caches, first layouts, worker start
        raw_rate(), step_rates(), vec_rate(), vec_rate(gvec)
    raws, steps, with_resets, vecs, gvecs = [], [], [], [], []
    t_end = time.perf_counter() + seconds
    while time.perf_counter() < t_end:
        raws.append(raw_rate())
        s, w = step_rates()
        steps.append(s)
        with_resets.append(w)
        vecs.append(vec_rate())
        gvecs.append(vec_rate(gvec))
    env.close()
    vec.close()
    gvec.close()
    raw_fps, step_sps, wr, vec_sps, gvec_sps = (float(np.median(x)) for x in (raws, steps, with_resets, vecs, gvecs))
    return {
        "scene": scene,
        "px": size,
        "renderer": env.renderer,
        "cull": env.cull,
        "raw_fps": raw_fps,
        "step_sps": step_sps,
        "step_sps_with_resets": wr,
        f"vec{n_vec}_sps": vec_sps,
        "step/raw": step_sps / raw_fps,
        f"vec{n_vec}/single": vec_sps / wr,
        f"gym_async{n_vec}_sps": gvec_sps,
        f"gym_async{n_vec}/single": gvec_sps / wr,
        f"vec{n_vec}/gym_async{n_vec}": vec_sps / gvec_sps,
        "reset_share": state["reset"] / (state["reset"] + state["step"]),
        "blocks": len(raws),
    }


def main(argv: Sequence[str] | None = None) -> int:
    ap = parser("env", __doc__ or "")
    ap.add_argument("--scenes", default="box", help="comma-separated scenes (default: box)")
    ap.add_argument("--sizes", default="64,128", help="comma-separated image sizes (px)")
    ap.add_argument("--seconds", type=float, default=20.0, help="measuring time per scene and size (s)")
    ap.add_argument("--renderers", default="auto", help="comma-separated env.renderer values: tiny, egl, auto")
    ap.add_argument("--vec", type=int, default=2, help="envs of the vector envs (default: 2)")
    ap.add_argument(
        "--cull",
        default="on",
        help="off, on or off,on: TinyRenderer culling (off,on measures both, one after the other per scene)",
    )
    args = ap.parse_args(argv)
    seconds = 3.0 if args.quick else args.seconds
    culls = [{"off": False, "on": True}[c] for c in args.cull.split(",")]
    rows = []
    for size in (int(s) for s in args.sizes.split(",")):
        for scene in args.scenes.split(","):
            for renderer in args.renderers.split(","):
                for cull in culls:
                    rows.append(measure(scene, size, seconds, n_vec=args.vec, renderer=renderer, cull=cull))
    base = {(r["px"], r["renderer"], r["cull"]): r["step_sps"] for r in rows if r["scene"] == rows[0]["scene"]}
    for r in rows:  # every scene against the first one at the same size, renderer and culling
        r[f"vs_{rows[0]['scene']}"] = r["step_sps"] / base[(r["px"], r["renderer"], r["cull"])]
        if len(culls) > 1 and r["cull"]:
            same = ("scene", "px", "renderer")
            off = next(o for o in rows if all(o[k] == r[k] for k in same) and not o["cull"])
            r["cull_gain"] = r["step_sps"] / off["step_sps"]
    write_results("env", rows, args.out)
    return 0
