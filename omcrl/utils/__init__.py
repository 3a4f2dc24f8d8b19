"""Small shared helpers: atomic file writes, seeding, thread settings."""

from omcrl.utils.io import atomic_save_torch, atomic_write_bytes, atomic_write_text
from omcrl.utils.runtime import seed_everything, set_threads

__all__ = ["atomic_save_torch", "atomic_write_bytes", "atomic_write_text", "seed_everything", "set_threads"]
