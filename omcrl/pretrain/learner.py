"""One contrastive learner for OMC and the CURL family; variants are flags of :class:`PretrainConfig`.

OMC (paper IV-B):  q_i = ξ(φ(f(h̄_i)))  over a masked sequence,  k_i = φ_k(f_k(h_i))  (``dual_transformer``:
                   k = ξ_k(φ_k(f_k(h)))) over the unmasked one; masked InfoNCE, cosine similarity / τ.
CURL:              q = φ(f(crop₁(h_t))),  k = φ_k(f_k(crop₂(h_t))),  logits q^T W k.
CURL-cons:         as CURL with the key from h_{t+cons_stride} of the same episode.
``use_projection=False`` makes φ (and φ_k) the identity. Key networks follow
θ_k ← m·θ + (1−m)·θ_k after every optimiser step and never receive gradients.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import Any

import torch
from torch import nn

from omcrl.models.encoder import PixelEncoder, Projection
from omcrl.models.transformer import TemporalTransformer
from omcrl.pretrain.losses import bilinear_info_nce, masked_info_nce
from omcrl.pretrain.masking import mask_sequence
from omcrl.utils.precision import autocast


def transformer_lr_factor(step: int, warmup: int) -> float:
    """Multiplier of lr_transformer at 1-based ``step``: linear warm-up to 1 at ``warmup``,
    then √(warmup/step).

    ``warmup=0`` gives pure inverse-square-root decay from step 1.
    """
    step = max(int(step), 1)
    w = max(int(warmup), 1)
    return min(step / w, math.sqrt(w / step)) if warmup > 0 else 1.0 / math.sqrt(step)


def color_jitter(seq: torch.Tensor, strength: float, generator: torch.Generator | None = None) -> torch.Tensor:
    """Random colour gains per sequence: (B, T, 3L, H, W) on the 0–255 scale → float, same shape.

    Each sequence gets one brightness factor and one gain per RGB channel, each uniform in [1 − s, 1 + s], applied
    to all T stacks and L frames alike (the look of a whole flight changes, its content does not); results are
    clipped to 255. Multiplicative, so masked (all-zero) stacks stay zero.
    """
    B = seq.shape[0]
    L = seq.shape[2] // 3
    u = torch.rand(B, 4, generator=generator) * 2 - 1
    gains = (1 + strength * u[:, :3]) * (1 + strength * u[:, 3:])  # (B, 3)
    g = gains.repeat(1, L).view(B, 1, 3 * L, 1, 1)
    return (seq.float() * g).clamp_(0, 255)


@dataclass(frozen=True)
class Objective:
    """A pretraining objective (``pretrain.method``), chosen once by :func:`objective`: what the learner samples and
    how it scores it each iteration, and the run name of its variants.

    Attributes
    ----------
    name : ``omc`` | ``curl`` | ``curl_cons``.
    sequences : True: masked sequences of T stacks, the masked latents reconstructed through the Transformer ξ
        (OMC); False: pairs of stacks matched through the bilinear W (the CURL family).
    consecutive : a pair is h_t and h_{t+cons_stride} of one episode (CURL-cons), not two crops of h_t (CURL).
    """

    name: str
    sequences: bool
    consecutive: bool = False

    def sequence_stride(self, p: Any) -> int:
        """Steps between the stacks of a sampled sequence (``seq_stride``; 1 for the pair objectives)."""
        return p.seq_stride if self.sequences else 1

    def candidates(self, p: Any) -> int:
        """Keys each query is scored against (its positive included): all B·T keys of the batch; the T keys of
        its own sequence for OMC without ``batch_negatives``. The CURL family sees B·T pairs per iteration (as
        many stacks as OMC)."""
        return p.seq_len if self.sequences and not p.batch_negatives else p.batch_size * p.seq_len

    def run_name(self, p: Any) -> str:
        """The run folder's name: the objective plus every ablation flag that differs from the paper's setting."""
        name = self.name
        if self.sequences:
            if p.mask_prob != 0.5:
                name += f"-rho{p.mask_prob:g}"
            if not p.use_projection:
                name += "-nophi"
            if p.dual_transformer:
                name += "-dualT"
            if not p.batch_negatives:
                name += "-seqneg"
            if p.seq_stride != 1:
                name += f"-stride{p.seq_stride}"
        else:
            if p.use_projection:
                name += "-phi"
            if self.consecutive and p.cons_stride != 1:
                name += f"-stride{p.cons_stride}"
        return name

    def loss(
        self, learner: ContrastiveLearner, sampler: Any, generator: torch.Generator
    ) -> tuple[torch.Tensor, dict[str, float]]:
        """One iteration's batch from ``sampler`` (:class:`omcrl.data.sampler.SequenceSampler`) and its loss."""
        p = learner.cfg
        if self.sequences:
            seq = sampler.sample_sequences()
            pool = sampler.sample_stacks(p.batch_size)
            return learner.omc_loss(seq, generator, pool)
        stride = p.cons_stride if self.consecutive else 0
        anchor, positive = sampler.sample_pairs(p.batch_size * p.seq_len, stride=stride)
        return learner.curl_loss(anchor, positive)


OBJECTIVES: dict[str, Objective] = {
    o.name: o for o in (Objective("omc", True), Objective("curl", False), Objective("curl_cons", False, True))
}


def objective(p: Any) -> Objective:
    """The :class:`Objective` of a :class:`omcrl.config.PretrainConfig` (its ``method``)."""
    if p.method not in OBJECTIVES:
        raise ValueError(f"pretrain.method: got {p.method!r}, expected one of {list(OBJECTIVES)}")
    return OBJECTIVES[p.method]


class ContrastiveLearner(nn.Module):
    """Online networks f, φ (+ ξ for OMC, W for CURL) and their momentum copies.

    Parameters
    ----------
    cfg : :class:`omcrl.config.PretrainConfig`.
    frame_stack : L; inputs are (…, 3L, crop_to, crop_to) on the 0–255 scale.
    """

    def __init__(self, cfg, frame_stack: int) -> None:
        super().__init__()
        self.cfg = cfg
        d = cfg.feature_dim
        self.f = PixelEncoder(frame_stack, cfg.crop_to, d)
        self.phi = Projection(d, cfg.proj_hidden, d) if cfg.use_projection else nn.Identity()
        self.f_k, self.phi_k = copy.deepcopy(self.f), copy.deepcopy(self.phi)
        self.xi = self.xi_k = self.W = None
        if objective(cfg).sequences:
            self.xi = TemporalTransformer(d, cfg.transformer_blocks, cfg.transformer_ffn, max_len=max(cfg.seq_len, 64))
            if cfg.dual_transformer:
                self.xi_k = copy.deepcopy(self.xi)
        else:
            self.W = nn.Parameter(torch.rand(d, d))  # CURL's initialisation
        for m in self._key_modules():
            m.requires_grad_(False)
        # "fp32" or "bf16" (resolved, omcrl.utils.precision): the networks' forward passes under autocast.
        self.precision = "fp32"

    def _pairs(self) -> list[tuple[nn.Module, nn.Module]]:
        pairs = [(self.f, self.f_k), (self.phi, self.phi_k)]
        if self.xi_k is not None:
            pairs.append((self.xi, self.xi_k))
        return pairs

    def _key_modules(self) -> list[nn.Module]:
        return [k for _, k in self._pairs()]

    def param_groups(self) -> list[dict]:
        """Adam groups: ``encoder`` (f, φ, W) at lr_encoder and ``transformer`` (ξ) at lr_transformer."""
        enc = [*self.f.parameters(), *self.phi.parameters()] + ([self.W] if self.W is not None else [])
        groups = [{"params": enc, "lr": self.cfg.lr_encoder, "name": "encoder"}]
        if self.xi is not None:
            groups.append({"params": list(self.xi.parameters()), "lr": self.cfg.lr_transformer, "name": "transformer"})
        return groups

    @torch.no_grad()
    def momentum_update(self) -> None:
        """θ_k ← m·θ + (1−m)·θ_k for f_k, φ_k (and ξ_k), m = cfg.momentum."""
        m = self.cfg.momentum
        for online, key in self._pairs():
            for p, pk in zip(online.parameters(), key.parameters()):
                pk.mul_(1.0 - m).add_(p.detach(), alpha=m)

    @property
    def device(self) -> torch.device:
        """Where the networks are (inputs built on the CPU are moved here)."""
        return next(self.f.parameters()).device

    def embed(self, x: torch.Tensor, key: bool = False) -> torch.Tensor:
        """φ(f(x)) (or φ_k(f_k(x))) for stacks (N, 3L, H, W) → (N, d)."""
        return self.phi_k(self.f_k(x)) if key else self.phi(self.f(x))

    def omc_loss(
        self, seq: torch.Tensor, generator: torch.Generator | None = None, pool: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, dict]:
        """Masked contrastive loss for sequences (B, T, 3L, H, W); ``pool`` (N, 3L, H, W) feeds swaps."""
        B, T = seq.shape[:2]
        masked, mask, _ = mask_sequence(seq, self.cfg.mask_prob, generator, pool)
        keys_in = seq
        if self.cfg.color_jitter > 0:
            # Query and key views of a sequence get different colours: matching them must not rely on colour.
            masked = color_jitter(masked, self.cfg.color_jitter, generator)
            keys_in = color_jitter(seq, self.cfg.color_jitter, generator)
        # Masks and colour draws come from CPU generators (the same on any device); the networks' device gets
        # one batch.
        dev = self.device
        masked, keys_in, mask = masked.to(dev), keys_in.to(dev), mask.to(dev)
        with autocast(self.precision, dev.type):
            q = self.xi(self.embed(masked.flatten(0, 1)).view(B, T, -1))
            with torch.no_grad():
                k = self.embed(keys_in.flatten(0, 1), key=True).view(B, T, -1)
                if self.xi_k is not None:
                    k = self.xi_k(k)
        # The loss in float32 (bf16 only inside the networks).
        loss, acc = masked_info_nce(q.float(), k.float(), mask, self.cfg.temperature, self.cfg.batch_negatives)
        return loss, {
            "loss": float(loss.detach()),
            "accuracy": float(acc),
            "mask_fraction": float(mask.float().mean()),
        }

    def curl_loss(self, anchor: torch.Tensor, positive: torch.Tensor) -> tuple[torch.Tensor, dict]:
        """CURL / CURL-cons loss for stacks (N, 3L, H, W): anchor online, positive via the keys."""
        anchor, positive = anchor.to(self.device), positive.to(self.device)
        with autocast(self.precision, self.device.type):
            q = self.embed(anchor)
            with torch.no_grad():
                k = self.embed(positive, key=True)
        loss, acc = bilinear_info_nce(q.float(), k.float(), self.W)
        return loss, {"loss": float(loss.detach()), "accuracy": float(acc)}
