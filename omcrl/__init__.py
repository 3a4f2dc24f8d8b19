"""omcrl: a reproduction kit for Oracle-Guided Masked Contrastive Reinforcement Learning (OMC-RL)."""

__version__ = "0.1.0"
