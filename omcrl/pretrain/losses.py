"""Contrastive losses: masked InfoNCE with cosine similarity (paper Eq. 1, 5) and CURL's bilinear InfoNCE."""

from __future__ import annotations

import torch
import torch.nn.functional as F


def _ce_and_accuracy(logits: torch.Tensor, target: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean cross-entropy and top-1 accuracy (is the argmax the positive?) of ``logits`` (N, K)."""
    if len(logits) == 0:  # nothing selected: a zero loss that still belongs to the graph
        return logits.sum() * 0.0, torch.tensor(float("nan"))
    loss = F.cross_entropy(logits, target)
    acc = (logits.detach().argmax(-1) == target).float().mean()
    return loss, acc


def masked_info_nce(
    q: torch.Tensor, k: torch.Tensor, mask: torch.Tensor, temperature: float, batch_negatives: bool = True
) -> tuple[torch.Tensor, torch.Tensor]:
    """InfoNCE over the masked positions.

    Parameters
    ----------
    q : (B, T, D) queries (ξ outputs); k : (B, T, D) keys (momentum branch, no grad needed).
    mask : bool (B, T), M_i; only masked positions contribute (mean over them).
    temperature : τ; similarities are cosine.
    batch_negatives : False — Eq. (5) as written: candidates for q_{b,i} are the T keys k_{b,1..T} of its own
        sequence. True — the keys of all B·T positions of the batch are candidates
        (more, and easier, negatives).

    Returns
    -------
    loss : scalar; accuracy : scalar, fraction of masked queries whose most similar key is the positive.
    """
    B, T, _ = q.shape
    qn, kn = F.normalize(q, dim=-1), F.normalize(k, dim=-1)
    if batch_negatives:
        logits = qn.reshape(B * T, -1) @ kn.reshape(B * T, -1).T / temperature  # (BT, BT)
        target = torch.arange(B * T)
    else:
        logits = (qn @ kn.transpose(1, 2) / temperature).reshape(B * T, T)  # (BT, T)
        target = torch.arange(T).repeat(B)
    sel = mask.reshape(-1)
    return _ce_and_accuracy(logits[sel], target[sel])


def bilinear_info_nce(q: torch.Tensor, k: torch.Tensor, W: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """CURL loss: logits_ij = q_i^T W k_j (N, N), positives on the diagonal; returns (loss, accuracy).

    The row maximum is subtracted for numerical stability, as in CURL (it does not change the loss).
    """
    logits = q @ W @ k.T
    logits = logits - logits.detach().max(dim=1, keepdim=True).values
    return _ce_and_accuracy(logits, torch.arange(len(q)))
