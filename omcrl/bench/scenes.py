"""``python -m omcrl.bench scenes``: the cost of generating a layout, batched placement against one by one.

A layout is generated at every episode reset (``env.layout_every`` = 1), so in a crowded scene its generator is a
visible part of an env step. The generators place structures with a rejection sampler
(``omcrl.scenes.registry._Placer``) that tests its first candidates one by one and the rest in one numpy batch,
with the same draws and the same layouts as testing every candidate one by one. For each scene this measures both,
interleaved layout by layout on the same episode seeds in one process, and reports:

* ``batched_ms`` and ``one_by_one_ms`` — mean milliseconds per layout (the generator alone, no PyBullet bodies);
* ``speedup`` — one_by_one_ms / batched_ms;
* ``same`` — whether the two gave the same obstacles for every seed (they must).
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np

from omcrl.bench import parser, write_results
from omcrl.scenes import registry

# The training scenes and the crowded unseen ones first: where a reset costs most.
SCENES = ("box-v2", "tree-v2", "barrier-v2", "furniture-v2", "box-v0", "tree-v0", "barrier-v0", "furniture-v1")


def measure(scene: str, layouts: int, arena_half: float = 8.0, seed0: int = 0) -> dict:
    """Mean ms per layout of ``scene`` with the batched and the one-by-one placer over ``layouts`` seeds."""
    spec = registry.scene_spec(scene)
    times = {True: 0.0, False: 0.0}
    same = True
    for k in range(layouts):
        out = {}
        for batched in (True, False) if k % 2 == 0 else (False, True):  # alternate who goes first
            registry._Placer.batched = batched
            rng = np.random.default_rng([seed0 + k, spec.stream])
            t0 = time.perf_counter()
            out[batched] = spec.generator(rng, arena_half, spec.default_count)
            times[batched] += time.perf_counter() - t0
        same &= out[True] == out[False]
    registry._Placer.batched = True
    batched_ms, single_ms = (1000 * times[b] / layouts for b in (True, False))
    return {
        "scene": scene,
        "layouts": layouts,
        "batched_ms": batched_ms,
        "one_by_one_ms": single_ms,
        "speedup": single_ms / batched_ms,
        "same": same,
    }


def main(argv: Sequence[str] | None = None) -> int:
    ap = parser("scenes", __doc__ or "")
    ap.add_argument("--scenes", default=",".join(SCENES), help="comma-separated scene ids")
    ap.add_argument("--layouts", type=int, default=200, help="layouts per scene (default: 200)")
    ap.add_argument("--seed0", type=int, default=0, help="first episode seed (default: 0)")
    args = ap.parse_args(argv)
    layouts = 20 if args.quick else args.layouts
    rows = [measure(s, layouts, seed0=args.seed0) for s in args.scenes.split(",")]
    write_results("scenes", rows, args.out, seed0=args.seed0)
    return 0 if all(r["same"] for r in rows) else 1
