"""Scenes: the versioned registry of :class:`SceneSpec` (generator, materials, surroundings) and the geometry
they are made of. No simulator here: the config validates scene names against this registry, and
:mod:`omcrl.envs` builds PyBullet worlds from it (see :mod:`omcrl.scenes.registry` for the scenes themselves)."""

from omcrl.scenes.geometry import Geometry, Primitive
from omcrl.scenes.registry import (
    FURNITURE,
    PAPER_SUITE,
    SCENE_SPECS,
    SCENES,
    STRESS_SCENES,
    FixedLayout,
    SceneSpec,
    course_scene,
    decor,
    families,
    generate_scene,
    is_stress,
    is_unseen,
    layout_to_primitives,
    register_scene,
    scene_id,
    scene_key,
    scene_label,
    scene_spec,
)

__all__ = [
    "FURNITURE",
    "PAPER_SUITE",
    "SCENES",
    "SCENE_SPECS",
    "STRESS_SCENES",
    "FixedLayout",
    "Geometry",
    "Primitive",
    "SceneSpec",
    "course_scene",
    "decor",
    "families",
    "generate_scene",
    "is_stress",
    "is_unseen",
    "layout_to_primitives",
    "register_scene",
    "scene_id",
    "scene_key",
    "scene_label",
    "scene_spec",
]
