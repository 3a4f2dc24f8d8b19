"""BERT-style masking of whole observation stacks (paper IV-B, "Data Collection").

Each position i of a sequence is selected with probability ρ_m (M_i ~ Bernoulli(ρ_m)). A selected stack is
replaced by zeros (80 %), by another stack h_j, j ≠ i (10 %), or kept unchanged (10 %); the loss is computed
on all selected positions, including the kept ones, as in BERT.
"""

from __future__ import annotations

import torch

OP_NONE, OP_ZERO, OP_REPLACE, OP_KEEP = 0, 1, 2, 3


def sample_mask_ops(
    shape: tuple[int, ...], mask_prob: float, generator: torch.Generator | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Draw the mask M and the operation per position.

    Returns
    -------
    mask : bool (shape) — M_i.
    ops : int64 (shape) — OP_NONE where not masked, else OP_ZERO / OP_REPLACE / OP_KEEP with p 0.8/0.1/0.1.
    """
    mask = torch.rand(shape, generator=generator) < mask_prob
    u = torch.rand(shape, generator=generator)
    ops = torch.where(u < 0.8, OP_ZERO, torch.where(u < 0.9, OP_REPLACE, OP_KEEP))
    return mask, torch.where(mask, ops, torch.full_like(ops, OP_NONE))


def apply_mask_ops(
    seq: torch.Tensor,
    ops: torch.Tensor,
    pool: torch.Tensor | None = None,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """Masked copy h̄ of ``seq`` (B, T, C, H, W) following ``ops`` (B, T).

    Replacements come from ``pool`` (N, C, H, W) — stacks drawn at random from the dataset — when given;
    otherwise from the other B·T − 1 stacks of the batch, so j ≠ i holds by construction.
    """
    out = seq.clone()
    out[ops == OP_ZERO] = 0
    rep = (ops == OP_REPLACE).flatten().nonzero().squeeze(1)
    if len(rep):
        flat = out.view(-1, *seq.shape[2:])
        if pool is not None:
            j = torch.randint(0, len(pool), (len(rep),), generator=generator)
            flat[rep] = pool[j].to(seq.dtype)
        else:
            src = seq.reshape(-1, *seq.shape[2:])
            j = torch.randint(0, len(src) - 1, (len(rep),), generator=generator)
            j = j + (j >= rep).long()  # skip i itself
            flat[rep] = src[j]
    return out


def mask_sequence(
    seq: torch.Tensor,
    mask_prob: float,
    generator: torch.Generator | None = None,
    pool: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """h̄ = M·h^m + (1−M)·h for sequences (B, T, C, H, W); returns (masked, mask (B, T), ops (B, T))."""
    mask, ops = sample_mask_ops(tuple(seq.shape[:2]), mask_prob, generator)
    return apply_mask_ops(seq, ops, pool, generator), mask, ops
