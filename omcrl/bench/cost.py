"""``python -m omcrl.bench cost --preset paper [--cores N]``: per-unit rates of a preset's jobs on a CPU node.

Measured on this machine at the preset's shapes, each on its own (no training is run):

* ``env`` — one env's steps/s (render and physics, resets included) at ``env.image_size``;
* ``frozen fwd`` — the frozen pixel encoder's forward per stack, in batches of ``rl.n_envs`` (no grad);
* ``depth fwd`` — the oracle's depth encoder forward per stack (the student's guide; the oracle's rollouts);
* ``pixel fwd+bwd`` / ``depth fwd+bwd`` — one trainable encoder's forward and backward per sample, in
  minibatches of ``--minibatch`` (the per-sample cost of a PPO update; the preset's minibatch of 1,024 at
  192 px does not fit a short benchmark);
* ``pretrain omc`` / ``pretrain curl`` — optimiser steps/s at the preset's pretraining shape
  (:func:`omcrl.bench.pretrain.measure`).

From these it writes the rates :func:`omcrl.pipeline.plan.sweep_cost` takes (units/s per ``rate_key``) for a node with
``--cores`` cores. The model: an env step costs ``1 / (env × min(n_envs, cores))`` (env workers in parallel) plus the
rollout's forwards per step; a trainer whose encoder learns adds ``epochs ×`` its fwd+bwd per sample; the network
terms shrink by ``this machine's threads / cores`` (linear scaling: optimistic); evaluation episodes take
``--episode-steps`` steps (an assumption, printed). These are CPU-node rates, not GPU ones.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from omcrl.bench import parser, timeit, write_results
from omcrl.bench.env import _walk
from omcrl.bench.pretrain import measure as pretrain_measure
from omcrl.config import Config, load_config
from omcrl.envs import make_env
from omcrl.models.encoder import DepthEncoder, PixelEncoder
from omcrl.utils.runtime import cpu_count


def _env_rate(cfg: Config, seconds: float) -> float:

    env = make_env(cfg.env.scene, seed=0, config=cfg.env)
    env.reset(seed=0)
    acts = _walk(np.random.default_rng(0), 100_000)
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds or n < 5:
        _, _, term, trunc, _ = env.step(acts[n % len(acts)])
        n += 1
        if term or trunc:
            env.reset()
    rate = n / (time.perf_counter() - t0)
    env.close()
    return rate


def _per_item(fn, items: int, min_time: float) -> float:
    """Seconds per item of ``fn()``, which processes ``items`` items (median call)."""
    return timeit(fn, min_time, warmup=1, max_calls=50)["median_s"] / items


def measure(cfg: Config, minibatch: int, env_seconds: float, min_time: float, pretrain_shape: str) -> dict:

    L, S, E = cfg.env.frame_stack, cfg.pretrain.crop_to, cfg.env.image_size
    d, n = cfg.pretrain.feature_dim, cfg.rl.n_envs
    torch.manual_seed(0)
    out: dict[str, float] = {"env": _env_rate(cfg, env_seconds)}
    f = PixelEncoder(L, S, d).eval()
    g = DepthEncoder(L, E, d).eval()
    rgb = torch.randint(0, 256, (n, 3 * L, S, S), dtype=torch.uint8).float()
    depth = torch.rand(n, L, E, E) * 10
    with torch.no_grad():
        out["frozen fwd"] = _per_item(lambda: f(rgb), n, min_time)
        out["depth fwd"] = _per_item(lambda: g(depth), n, min_time)
    for name, net, x in (
        ("pixel fwd+bwd", PixelEncoder(L, S, d).train(), torch.randint(0, 256, (minibatch, 3 * L, S, S)).float()),
        ("depth fwd+bwd", DepthEncoder(L, E, d).train(), torch.rand(minibatch, L, E, E) * 10),
    ):
        opt = torch.optim.Adam(net.parameters())

        def step(net=net, x=x, opt=opt) -> None:
            opt.zero_grad(set_to_none=True)
            net(x).square().mean().backward()
            opt.step()

        out[name] = _per_item(step, minibatch, min_time)
    for m in ("omc", "curl"):
        out[f"pretrain {m}"] = pretrain_measure(m, pretrain_shape, min_time, 3)["it_per_s"]
    return out


def rates_for_node(cfg: Config, m: dict, cores: int, threads: int, episode_steps: int) -> dict[str, float]:
    """Units/s per ``rate_key`` on a node of ``cores`` cores, from the measurements ``m`` (see the module doc)."""
    net = threads / max(cores, 1)  # network terms scale with the cores they get
    env_s = 1.0 / (m["env"] * min(cfg.rl.n_envs, cores))
    ep = cfg.rl.epochs
    step_s = {
        "train:frozen": env_s + net * (m["frozen fwd"] + m["depth fwd"]),  # ours: the oracle guide's forward too
        "train:oracle": env_s + net * (m["depth fwd"] + ep * m["depth fwd+bwd"]),
        "train:pixel": env_s + net * (m["frozen fwd"] + ep * m["pixel fwd+bwd"]),
    }
    rates = {k: 1.0 / v for k, v in step_s.items()}
    rates["pretrain"] = min(m["pretrain omc"], m["pretrain curl"]) / net
    rates["evaluate"] = 1.0 / (episode_steps * (env_s + net * m["frozen fwd"]))
    rates["collect"] = 1.0 / (cfg.data.max_steps / (m["env"] * min(cfg.data.n_envs, cores)))
    return rates


def main(argv: Sequence[str] | None = None) -> int:
    ap = parser("cost", __doc__ or "")
    ap.add_argument("--preset", default="paper", help="preset whose shapes are measured (default: paper)")
    ap.add_argument("--cores", type=int, default=0, help="cores of the modelled node (default: this machine's)")
    ap.add_argument("--minibatch", type=int, default=32, help="samples per fwd+bwd measurement (default: 32)")
    ap.add_argument("--episode-steps", type=int, default=300, help="assumed steps per evaluation episode")
    ap.add_argument("--rates-out", default=None, help="also write the rates as JSON for `sweep --plan --rates`")
    args = ap.parse_args(argv)

    cfg = load_config(args.preset)
    threads = torch.get_num_threads()
    cores = args.cores or cpu_count()
    env_s, min_t = (2.0, 0.5) if args.quick else (10.0, 3.0)
    shape = "paper" if args.preset == "paper" else "quick"
    m = measure(cfg, args.minibatch, env_s, min_t, shape)
    rates = rates_for_node(cfg, m, cores, threads, args.episode_steps)
    rows = [{"measured": k, "value": v, "unit": "steps/s" if k == "env" else "it/s" if "pretrain" in k else "s/item"}
            for k, v in m.items()]  # fmt: skip
    rows += [{"measured": f"rate {k}", "value": v, "unit": "units/s on the node"} for k, v in rates.items()]
    meta = {"preset": args.preset, "cores": cores, "threads": threads, "episode_steps": args.episode_steps}
    write_results("cost", rows, args.out, **meta)
    if args.rates_out:
        Path(args.rates_out).write_text(json.dumps(rates, indent=1) + "\n", encoding="utf-8")
        print(f"# rates for `python -m omcrl sweep all --preset {args.preset} --plan --rates {args.rates_out}`")
    return 0
