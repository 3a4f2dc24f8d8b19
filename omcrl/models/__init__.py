"""Networks: pixel encoder f, depth encoder f^o, projection φ, Transformer ξ and the frozen-encoder artifact.

Actor/critic heads live in their own module of this package (written with the RL stage).
"""

from omcrl.models.artifact import (
    EncoderError,
    FrozenEncoder,
    build_encoder,
    encoder_meta,
    load_encoder,
    random_encoder,
    save_encoder,
)
from omcrl.models.encoder import ConvEncoder, DepthEncoder, PixelEncoder, Projection, conv_out_size
from omcrl.models.transformer import TemporalTransformer, TransformerBlock, sinusoidal_encoding

__all__ = [
    "ConvEncoder",
    "DepthEncoder",
    "EncoderError",
    "FrozenEncoder",
    "PixelEncoder",
    "Projection",
    "TemporalTransformer",
    "TransformerBlock",
    "build_encoder",
    "conv_out_size",
    "encoder_meta",
    "load_encoder",
    "random_encoder",
    "save_encoder",
    "sinusoidal_encoding",
]
