"""Networks: pixel encoder f, depth encoder f^o, projection φ, Transformer ξ and the frozen-encoder artifact.

Policy networks: feature extractors by observation kind (:mod:`omcrl.models.features`) and the actor-critic
heads (:mod:`omcrl.models.actor_critic`).
"""

from omcrl.models.actor_critic import ActorCritic
from omcrl.models.artifact import (
    EncoderError,
    FrozenEncoder,
    build_encoder,
    encoder_meta,
    encoder_payload,
    load_encoder,
    random_encoder,
    save_encoder,
)
from omcrl.models.encoder import ConvEncoder, DepthEncoder, PixelEncoder, Projection, conv_out_size
from omcrl.models.features import (
    FEATURE_KINDS,
    FeatureExtractor,
    IdentityFeatures,
    OracleFeatures,
    PixelFeatures,
    StudentFeatures,
    build_features,
    register_feature_kind,
)
from omcrl.models.transformer import TemporalTransformer, TransformerBlock, sinusoidal_encoding

__all__ = [
    "FEATURE_KINDS",
    "ActorCritic",
    "ConvEncoder",
    "DepthEncoder",
    "EncoderError",
    "FeatureExtractor",
    "FrozenEncoder",
    "IdentityFeatures",
    "OracleFeatures",
    "PixelEncoder",
    "PixelFeatures",
    "Projection",
    "StudentFeatures",
    "TemporalTransformer",
    "TransformerBlock",
    "build_encoder",
    "build_features",
    "conv_out_size",
    "encoder_meta",
    "encoder_payload",
    "load_encoder",
    "random_encoder",
    "register_feature_kind",
    "save_encoder",
    "sinusoidal_encoding",
]
