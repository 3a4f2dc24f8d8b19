"""The kit's configuration error, below every layer so that helpers in :mod:`omcrl.utils` can raise it
(:mod:`omcrl.config` re-exports it: ``from omcrl.config import ConfigError`` is the usual spelling)."""


class ConfigError(ValueError):
    """A configuration value is invalid; the message names the field, the value and what is allowed."""
