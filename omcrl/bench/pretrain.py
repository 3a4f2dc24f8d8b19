"""``python -m omcrl.bench pretrain``: pretraining throughput and memory for OMC and CURL.

Shapes: ``quick`` (from the quick preset: crop 56 px, B = 16, T = 8, d = 128) and ``paper`` (crop 192 px,
B = 32, T = 16, d = 384, paper V-D). The data is synthetic uint8 stacks already cropped, in memory, so no
dataset is needed and only the learner's forward/backward/optimiser step is timed (the sampler is excluded).
One *iteration* is one optimiser step: OMC on B sequences of T stacks (B·T stacks through f), CURL on B·T
anchor/positive pairs (the trainer feeds CURL as many stacks as OMC, see :mod:`omcrl.pretrain.train`).

Reported per (method, shape):

* ``it_per_s`` — optimiser steps per second (median call time after one warm-up step);
* ``seq_per_s`` — B·it/s (sequences; for CURL, B·T pairs = the same number of stacks);
* ``stacks_per_s`` — B·T·it/s;
* ``peak_rss_mb`` — peak resident memory *above the baseline before the learner and batch were built*,
  sampled from ``/proc/self/statm`` every 2 ms by a background thread (tracemalloc does not see torch's C++
  allocations, and ``ru_maxrss`` is a process-wide high-water mark that an earlier, larger measurement would
  mask; a 2 ms sampler can miss sub-millisecond spikes, so this is a slight underestimate);
* ``maxrss_mb`` — ``resource.getrusage(RUSAGE_SELF).ru_maxrss`` after the measurement (process high-water mark,
  for reference; it includes Python, torch and every earlier measurement).

The paper shape costs several seconds per iteration on a CPU; it runs a few iterations only. ``--device`` (cpu,
cuda, auto: as ``pretrain.device``) and ``--precision`` (fp32,bf16: as ``pretrain.precision``, each measured in turn
in this run) place the learner as the trainer does; on CUDA each step ends in a synchronisation, so a step's time is
its kernels' time. The batches stay uint8 in host memory, as the sampler hands them over.
"""

from __future__ import annotations

import gc
import resource
from collections.abc import Sequence

import torch

from omcrl.bench import parser, timeit, write_results
from omcrl.config import load_config
from omcrl.pretrain.learner import ContrastiveLearner
from omcrl.utils.memory import PeakRSS
from omcrl.utils.precision import section_precision
from omcrl.utils.runtime import resolve_device

SHAPES = {  # name -> pretrain overrides (quick is read from the quick preset)
    "quick": {},
    "paper": {
        "crop_from": 224,
        "crop_to": 192,
        "batch_size": 32,
        "seq_len": 16,
        "feature_dim": 384,
        "proj_hidden": 384,
        "transformer_ffn": 768,
    },
}


def measure(
    method: str,
    shape: str,
    min_time: float,
    max_calls: int,
    seed: int = 0,
    device: str = "cpu",
    precision: str = "fp32",
) -> dict:
    """Time ``max_calls`` (or ``min_time`` s of) optimiser steps of ``method`` at ``shape`` on ``device`` in
    ``precision``; one result row."""
    over = [f"pretrain.{k}={v}" for k, v in SHAPES[shape].items()]
    if method == "curl":
        over += ["pretrain.method=curl", "pretrain.use_projection=false"]
    cfg = load_config("quick", overrides=[*over, f"pretrain.device={device}", f"pretrain.precision={precision}"])
    dev = resolve_device(cfg.pretrain.device)
    p, L = cfg.pretrain, cfg.env.frame_stack
    torch.manual_seed(seed)
    gen = torch.Generator().manual_seed(seed)
    S, B, T = p.crop_to, p.batch_size, p.seq_len
    with PeakRSS() as mem:
        learner = ContrastiveLearner(p, L).to(dev)
        learner.precision = section_precision(p)
        opt = torch.optim.Adam(learner.param_groups())
        learner.train()
        if method == "omc":
            seq = torch.randint(0, 256, (B, T, 3 * L, S, S), dtype=torch.uint8, generator=gen)
            pool = torch.randint(0, 256, (B, 3 * L, S, S), dtype=torch.uint8, generator=gen)
        else:
            anchor = torch.randint(0, 256, (B * T, 3 * L, S, S), dtype=torch.uint8, generator=gen)
            positive = torch.randint(0, 256, (B * T, 3 * L, S, S), dtype=torch.uint8, generator=gen)

        def step() -> None:
            if method == "omc":
                loss, _ = learner.omc_loss(seq, gen, pool)
            else:
                loss, _ = learner.curl_loss(anchor, positive)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            learner.momentum_update()
            if dev.type == "cuda":
                torch.cuda.synchronize(dev)

        t = timeit(step, min_time, warmup=1, max_calls=max_calls)
    it_s = 1.0 / t["median_s"]
    return {
        "method": method,
        "shape": shape,
        "device": dev.type,
        "precision": learner.precision,
        "crop_px": S,
        "B": B,
        "T": T,
        "d": p.feature_dim,
        "iters": t["calls"],
        "s_per_it": t["median_s"],
        "it_per_s": it_s,
        "seq_per_s": B * it_s,
        "stacks_per_s": B * T * it_s,
        "peak_rss_mb": mem.delta_mb,
        "maxrss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def main(argv: Sequence[str] | None = None) -> int:
    ap = parser("pretrain", __doc__ or "")
    ap.add_argument("--shapes", default="quick,paper", help="comma-separated shapes: quick, paper")
    ap.add_argument("--methods", default="omc,curl", help="comma-separated methods: omc, curl")
    ap.add_argument("--threads", type=int, default=2, help="torch intra-op threads (default 2)")
    ap.add_argument("--paper-iters", type=int, default=3, help="timed iterations at the paper shape")
    ap.add_argument("--device", default="cpu", help="cpu, cuda or auto, as pretrain.device (default: cpu)")
    ap.add_argument("--precision", default="fp32", help="comma-separated precisions, as pretrain.precision (fp32,bf16)")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    rows = []
    # Smaller shapes first: each measurement's baseline RSS then already holds the earlier ones' freed memory.
    for shape in args.shapes.split(","):
        for method in args.methods.split(","):
            for prec in args.precision.split(","):
                on = {"device": args.device, "precision": prec}
                if shape == "paper":
                    calls = 1 if args.quick else args.paper_iters
                    rows.append(measure(method, shape, min_time=0.0, max_calls=calls, **on))
                else:
                    rows.append(measure(method, shape, min_time=1.0 if args.quick else 5.0, max_calls=10_000, **on))
                gc.collect()
    write_results("pretrain", rows, args.out, threads=args.threads)
    return 0
