"""Encoders, projection, Transformer and the frozen-encoder artifact."""

from __future__ import annotations

import math

import pytest
import torch

from omcrl.config import load_config
from omcrl.models import (
    DepthEncoder,
    EncoderError,
    PixelEncoder,
    Projection,
    TemporalTransformer,
    load_encoder,
    random_encoder,
    save_encoder,
    sinusoidal_encoding,
)

torch.set_num_threads(1)


def _cfg(tmp_path, **pre):
    over = {
        "results_dir": str(tmp_path / "res"),
        "env": {"image_size": 20, "frame_stack": 2},
        "pretrain": {"crop_from": 20, "crop_to": 16, "feature_dim": 12, "proj_hidden": 10, **pre},
    }
    return load_config("smoke", overrides=over)


def test_pixel_encoder_shapes_and_normalisation():
    torch.manual_seed(0)
    f = PixelEncoder(frame_stack=3, image_size=16, feature_dim=24)
    x = torch.randint(0, 256, (5, 9, 16, 16), dtype=torch.uint8)
    z = f(x)
    assert z.shape == (5, 24) and z.abs().max() < 1
    torch.testing.assert_close(z, f(x.float()))  # uint8 and 0-255 float agree
    assert [type(m).__name__ for m in f.convs] == ["Conv2d", "ReLU", "Conv2d", "ReLU"]
    assert f.convs[0].stride == (2, 2) and f.convs[2].stride == (1, 1) and f.convs[0].out_channels == 32
    with pytest.raises(ValueError, match=r"expected input \(B, 9, 16, 16\)"):
        f(torch.zeros(2, 9, 20, 20))


def test_depth_encoder_and_projection():
    g = DepthEncoder(frame_stack=3, image_size=16, feature_dim=8, far=10.0)
    d = torch.rand(4, 3, 16, 16) * 30
    assert g(d).shape == (4, 8)
    torch.testing.assert_close(g(d), g(d.clamp(max=10.0)))  # beyond the far plane is clipped
    phi = Projection(8, 16, 5)
    assert phi(torch.zeros(3, 7, 8)).shape == (3, 7, 5)


def test_transformer_positional_encoding_and_shape():
    pe = sinusoidal_encoding(10, 6)
    assert math.isclose(pe[3, 2].item(), math.sin(3 / 10000 ** (2 / 6)), rel_tol=1e-5)
    assert math.isclose(pe[3, 3].item(), math.cos(3 / 10000 ** (2 / 6)), rel_tol=1e-5)
    xi = TemporalTransformer(dim=6, n_blocks=2, ffn_dim=12)
    x = torch.randn(2, 5, 6)
    y = xi(x)
    assert y.shape == (2, 5, 6)
    w = xi.blocks[0].attention_weights(x)
    torch.testing.assert_close(w.sum(-1), torch.ones(2, 5))
    # Positions matter: swapping two tokens does not just swap the outputs.
    xs = x[:, [1, 0, 2, 3, 4]]
    assert not torch.allclose(xi(xs)[:, [1, 0, 2, 3, 4]], y, atol=1e-5)


def test_encoder_artifact_roundtrip_and_center_crop(tmp_path):
    cfg = _cfg(tmp_path)
    torch.manual_seed(0)
    f, phi = PixelEncoder(2, 16, 12), Projection(12, 10, 12)
    path = save_encoder(tmp_path / "enc.pt", f, phi, cfg, "abc123")
    enc = load_encoder(path, image_size=20, frame_stack=2)
    assert not enc.training and all(not p.requires_grad for p in enc.parameters())
    enc.train()
    assert not enc.training  # stays frozen
    assert enc.meta["dataset_fingerprint"] == "abc123" and enc.meta["method"] == "omc"
    x = torch.randint(0, 256, (3, 6, 20, 20), dtype=torch.uint8)
    with torch.no_grad():
        want = phi(f(x[..., 2:18, 2:18]))
        torch.testing.assert_close(enc(x), want)
        torch.testing.assert_close(enc(x[..., 2:18, 2:18]), want)
    assert enc(x).shape == (3, enc.feature_dim) and not enc(x).requires_grad
    # Without φ the output is f's.
    cfg2 = _cfg(tmp_path, use_projection=False)
    enc2 = load_encoder(save_encoder(tmp_path / "enc2.pt", f, None, cfg2))
    with torch.no_grad():
        torch.testing.assert_close(enc2(x), f(x[..., 2:18, 2:18]))


def test_load_encoder_errors(tmp_path):
    cfg = _cfg(tmp_path)
    path = save_encoder(tmp_path / "enc.pt", PixelEncoder(2, 16, 12), Projection(12, 10, 12), cfg)
    with pytest.raises(EncoderError, match=r"enc\.pt.*'image_size' expected 64.*trained with 20"):
        load_encoder(path, image_size=64)
    with pytest.raises(EncoderError, match=r"enc\.pt.*'frame_stack' expected 3.*trained with 2"):
        load_encoder(path, frame_stack=3)
    with pytest.raises(EncoderError, match=r"missing\.pt: file does not exist"):
        load_encoder(tmp_path / "missing.pt")
    torch.save({"weights": torch.zeros(2)}, tmp_path / "other.pt")
    with pytest.raises(EncoderError, match=r"other\.pt: not an omcrl encoder artifact"):
        load_encoder(tmp_path / "other.pt")
    (tmp_path / "text.pt").write_text("hello")
    with pytest.raises(EncoderError, match=r"text\.pt: not a readable encoder artifact"):
        load_encoder(tmp_path / "text.pt")
    enc = load_encoder(path)
    with pytest.raises(ValueError, match="expects images of 20 px"):
        enc(torch.zeros(1, 6, 18, 18))


def test_random_encoder_matches_config(tmp_path):
    enc = random_encoder(_cfg(tmp_path), seed=1)
    assert enc.meta["method"] == "random" and enc.frame_stack == 2 and enc.crop_from == 20
    assert enc(torch.zeros(2, 6, 20, 20)).shape == (2, 12)
    torch.testing.assert_close(random_encoder(_cfg(tmp_path), seed=1).f.fc.weight, enc.f.fc.weight)
