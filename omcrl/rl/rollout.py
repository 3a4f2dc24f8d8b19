"""The rollout runner: steps a vector env with the current policy and fills :class:`~omcrl.rl.ppo.Rollout`s.

Step accounting: every vector step counts ``n_envs`` env steps (including next-step-autoreset dummy steps,
which are real env calls, marked invalid and left out of the loss).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from omcrl.models.actor_critic import ActorCritic
from omcrl.rl.guidance import Guide, info_at
from omcrl.rl.ppo import NonFiniteLossError, Rollout
from omcrl.utils.runtime import to_device

# States per call of a batched guide: large enough to amortise reading the oracle's weights, small enough that
# the pending depth stacks stay small (256 · 3 · 224² float16 ≈ 77 MB at the paper's image size).
GUIDE_CHUNK = 256


def _autoreset_mode(env: Any) -> str:
    """'next' (gymnasium 1.x default) or 'same'; other modes are rejected."""
    mode = getattr(env, "metadata", {}).get("autoreset_mode", "NextStep")
    name = getattr(mode, "value", str(mode))
    if name == "NextStep":
        return "next"
    if name == "SameStep":
        return "same"
    raise ValueError(f"vector env autoreset_mode {name!r} is not supported (use NEXT_STEP or SAME_STEP)")


def _index_obs(obs: Any, idx: np.ndarray) -> Any:
    if isinstance(obs, dict):
        return {k: np.asarray(v)[idx] for k, v in obs.items()}
    return np.asarray(obs)[idx]


def _stack_final_obs(final_obs: np.ndarray, idx: np.ndarray) -> Any:
    items = [final_obs[i] for i in idx]
    if isinstance(items[0], dict):
        return {k: np.stack([np.asarray(it[k]) for it in items]) for k in items[0]}
    return np.stack([np.asarray(it) for it in items])


def _nonfinite_action(action: torch.Tensor, stored: dict[str, torch.Tensor], t: int, agent: torch.nn.Module) -> str:
    """Why the policy's actions (N, A) hold NaN/inf at rollout step ``t``: the observations it was given (named by
    key), else the policy's non-finite parameters (named), else an overflow of finite inputs through finite weights
    (the lanes' largest input magnitude per key and the largest weight are given)."""
    lanes = [int(i) for i in torch.nonzero(~torch.isfinite(action).all(-1)).flatten()]
    floats = {k: v for k, v in sorted(stored.items()) if v.is_floating_point()}
    keys = [k for k, v in floats.items() if not torch.isfinite(v[lanes]).all()]
    bad = [n for n, p in agent.named_parameters() if not torch.isfinite(p).all()]
    if keys:
        where = f"from non-finite observations ({', '.join(keys)})"
    elif bad:
        names = ", ".join(bad[:5]) + " ..." * (len(bad) > 5)
        where = f"from finite observations (the policy's weights are non-finite: {names})"
    else:
        mags = ", ".join(f"{k} {float(v[lanes].abs().max()):.3g}" for k, v in floats.items())
        w = max(float(p.detach().abs().max()) for p in agent.parameters())
        where = f"from finite observations and finite weights (an overflow; largest |input|: {mags}; |weight| {w:.3g})"
    return (
        f"non-finite action at rollout step {t} in env lane(s) {lanes}, {where}; training stopped, the last good "
        "checkpoint is kept (a resume starts from it)"
    )


class Runner:
    """Steps a gymnasium vector env with the current policy and fills :class:`Rollout` buffers.

    Keeps env state between rollouts (current observation, next-step-autoreset flags, running returns) and a
    list of finished episodes ``{"return", "length", **info["metrics"]}``.
    """

    def __init__(
        self, env: Any, agent: ActorCritic, guide: Guide | None, seed: int, guide_chunk: int | None = None
    ) -> None:
        self.env, self.agent, self.guide = env, agent, guide
        self.guide_batched = bool(getattr(guide, "batched", False))
        # Vector steps whose guide inputs are evaluated together (about ``guide_chunk`` states per call;
        # default GUIDE_CHUNK, read at run time so a benchmark can compare against per-step evaluation).
        chunk = GUIDE_CHUNK if guide_chunk is None else guide_chunk
        self.guide_every = max(1, chunk // env.num_envs)
        self.mode = _autoreset_mode(env)
        self.n = env.num_envs
        # The networks may live on a GPU; the rollout buffer stays in host memory (paper-scale pixel buffers
        # are gigabytes). Per vector step one batch goes up (the stored inputs) and one comes down (action,
        # log-prob, value, stored inputs made on the device); on the CPU every transfer is a no-op.
        self.device = next(agent.parameters()).device
        self.obs, self.infos = env.reset(seed=seed)
        self.stored = self._prepare(self.obs)
        self.starts = np.ones(self.n, bool)
        self.dummy = np.zeros(self.n, bool)  # next-step mode: this step only resets, the action is ignored
        self.ep_return = np.zeros(self.n)
        self.ep_len = np.zeros(self.n, int)
        self.episodes: list[dict] = []

    def collect(self, length: int, horizon: int, use_guide: bool) -> Rollout:
        n = self.n
        buf: dict[str, list] = {
            k: [] for k in ("obs", "act", "logp", "val", "rew", "term", "ends", "valid", "gm", "gs")
        }
        final_values: dict[tuple[int, int], float] = {}
        guided = use_guide and self.guide is not None
        pending: list[dict[str, torch.Tensor]] = []  # prepared guide inputs not evaluated yet (batched guides)
        host = torch.device("cpu")
        for t in range(length):
            action, logp, value, _, _ = (x.to(host) for x in self.agent.step(self.stored))
            if not torch.isfinite(action).all():
                raise NonFiniteLossError(_nonfinite_action(action, self.stored, t, self.agent))
            if guided and self.guide_batched:
                pending.append(self.guide.prepare(self.obs))
                if len(pending) == self.guide_every or t == length - 1:
                    self._flush_guide(pending, buf)
            elif guided:
                gm, gs = self.guide.distribution(self.obs, self.infos, self.starts)
                buf["gm"].append(torch.as_tensor(gm, dtype=torch.float32))
                buf["gs"].append(torch.as_tensor(gs, dtype=torch.float32))
            buf["obs"].append(to_device(self.stored, host))
            buf["act"].append(action)
            buf["logp"].append(logp)
            buf["val"].append(value)
            valid = ~self.dummy
            # The env sees the clipped action; the buffer keeps the unclipped sample (see ppo.py docstring).
            obs, rew, term, trunc, infos = self.env.step(np.clip(action.numpy(), -1.0, 1.0))
            rew = np.asarray(rew, dtype=np.float64)
            term, trunc = np.asarray(term, bool), np.asarray(trunc, bool)
            done = term | trunc
            buf["rew"].append(torch.as_tensor(rew, dtype=torch.float32))
            buf["term"].append(torch.as_tensor(term, dtype=torch.float32))
            cut = (t + 1) % horizon == 0 or t == length - 1
            buf["ends"].append(torch.as_tensor(done | cut, dtype=torch.float32))
            buf["valid"].append(torch.as_tensor(valid, dtype=torch.float32))
            self.ep_return[valid] += rew[valid]
            self.ep_len[valid] += 1
            ended = np.flatnonzero(done & valid)
            if self.mode == "same" and ended.size:
                # Same-step autoreset returns the reset obs; bootstrap truncations from the real final obs.
                with torch.no_grad():
                    _, _, v_final = self.agent(self._prepare(_stack_final_obs(infos["final_obs"], ended)))
                    v_final = v_final.to(host)
                for j, i in enumerate(ended):
                    final_values[(t, int(i))] = float(v_final[j])
            src = infos.get("final_info", {}) if self.mode == "same" else infos
            for i in ended:
                ep = {"return": float(self.ep_return[i]), "length": int(self.ep_len[i])}
                ep.update(info_at(src, int(i)).get("metrics", {}) if src else {})
                self.episodes.append(ep)
                self.ep_return[i], self.ep_len[i] = 0.0, 0
            if self.mode == "next":
                self.starts, self.dummy = self.dummy.copy(), done & valid
            else:
                self.starts, self.dummy = done.copy(), np.zeros(n, bool)
            self.obs, self.infos = obs, infos
            self.stored = self._prepare(obs)
        with torch.no_grad():
            _, _, last_value = self.agent(self.stored)
            last_value = last_value.to(host)
        values = torch.stack(buf["val"])
        # V(s_{t+1}) is the next slot's value; in next-step mode that slot holds an ended episode's final obs.
        next_values = torch.cat([values[1:], last_value[None]], dim=0)
        for (t, i), v in final_values.items():
            next_values[t, i] = v
        obs_t = {k: torch.stack([s[k] for s in buf["obs"]]) for k in buf["obs"][0]}
        return Rollout(
            obs=obs_t,
            actions=torch.stack(buf["act"]),
            log_probs=torch.stack(buf["logp"]),
            values=values,
            next_values=next_values,
            rewards=torch.stack(buf["rew"]),
            terminated=torch.stack(buf["term"]),
            ends=torch.stack(buf["ends"]),
            valid=torch.stack(buf["valid"]),
            guide_mean=torch.stack(buf["gm"]) if buf["gm"] else None,
            guide_std=torch.stack(buf["gs"]) if buf["gs"] else None,
        )

    def _prepare(self, obs: Any) -> dict[str, torch.Tensor]:
        """The policy's stored inputs for a batched observation, on the networks' device."""
        return to_device(self.agent.prepare(obs), self.device)

    def _flush_guide(self, pending: list[dict[str, torch.Tensor]], buf: dict[str, list]) -> None:
        """Evaluate a batched guide on the pending steps at once and append one (N, A) row per step."""
        stored = {k: torch.cat([p[k] for p in pending]) for k in pending[0]}
        mean, std = (x.cpu() for x in self.guide.distribution_stored(stored))
        buf["gm"].extend(mean.split(self.n))
        buf["gs"].extend(std.split(self.n))
        pending.clear()
