"""Temporal Transformer ξ (paper IV-B, Eq. 3-4): encoder-only, single-head self-attention, post-LayerNorm."""

from __future__ import annotations

import math

import torch
from torch import nn


def sinusoidal_encoding(length: int, dim: int) -> torch.Tensor:
    """Standard Transformer positional encoding p_i: (length, dim), sin on even and cos on odd features."""
    pos = torch.arange(length, dtype=torch.float32)[:, None]
    freq = torch.exp(torch.arange(0, dim, 2, dtype=torch.float32) * (-math.log(10000.0) / dim))
    pe = torch.zeros(length, dim)
    pe[:, 0::2] = torch.sin(pos * freq)
    pe[:, 1::2] = torch.cos(pos * freq[: dim // 2])
    return pe


class TransformerBlock(nn.Module):
    """x ← LN(x + Attn(x)); x ← LN(x + F(x)) with F a 2-layer ReLU MLP. (B, T, d) → (B, T, d).

    Attention is single-head with Q, K, V projections and scale 1/√d, as Eq. (3): z̃_i = Σ_j α_ij v_j
    (no output projection; with one head W_V already plays that role).
    """

    def __init__(self, dim: int, ffn_dim: int) -> None:
        super().__init__()
        self.q = nn.Linear(dim, dim)
        self.k = nn.Linear(dim, dim)
        self.v = nn.Linear(dim, dim)
        self.ffn = nn.Sequential(nn.Linear(dim, ffn_dim), nn.ReLU(), nn.Linear(ffn_dim, dim))
        self.ln1 = nn.LayerNorm(dim)
        self.ln2 = nn.LayerNorm(dim)
        self.scale = 1.0 / math.sqrt(dim)

    def attention_weights(self, x: torch.Tensor) -> torch.Tensor:
        """α: (B, T, T), rows sum to 1."""
        return torch.softmax(self.q(x) @ self.k(x).transpose(1, 2) * self.scale, dim=-1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.ln1(x + self.attention_weights(x) @ self.v(x))
        return self.ln2(x + self.ffn(x))


class TemporalTransformer(nn.Module):
    """ξ: (B, T, d) → (B, T, d). Sinusoidal positions are added once, before the first block.

    Parameters
    ----------
    dim : d, token size (output of φ, or of f without φ).
    n_blocks : number of blocks.
    ffn_dim : hidden width of each block's feed-forward MLP.
    max_len : longest sequence supported.
    """

    def __init__(self, dim: int, n_blocks: int, ffn_dim: int, max_len: int = 512) -> None:
        super().__init__()
        self.blocks = nn.ModuleList(TransformerBlock(dim, ffn_dim) for _ in range(n_blocks))
        self.register_buffer("pos", sinusoidal_encoding(max_len, dim), persistent=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.shape[1] > self.pos.shape[0]:
            raise ValueError(f"sequence length {x.shape[1]} exceeds max_len {self.pos.shape[0]}")
        x = x + self.pos[: x.shape[1]]
        for blk in self.blocks:
            x = blk(x)
        return x
