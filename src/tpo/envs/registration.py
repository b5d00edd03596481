"""Gymnasium ids of the navigation envs, registered when :mod:`tpo.envs` is imported
(without importing JAX: the entry points load on ``gymnasium.make``)."""

from __future__ import annotations

import gymnasium as gym

from tpo.envs.maps import bundled_maps


def register_envs(maps: list[str] | None = None) -> list[str]:
    """Register ``tpo/GridNav-NAME-v0``, ``tpo/ContinuousNav-NAME-v0`` and
    ``tpo/ContinuousNavHeading-NAME-v0`` for every map (default: the bundled ones),
    and ``tpo/RandomTMDP-v0`` (the arguments of :func:`tpo.envs.random_tmdp.random_tmdp`).
    Idempotent; returns the ids."""
    ids = []
    for name in bundled_maps() if maps is None else maps:
        for env_id, entry, kwargs in (
            (f"tpo/GridNav-{name}-v0", "GridNavEnv", {}),
            (f"tpo/ContinuousNav-{name}-v0", "ContinuousNavEnv", {}),
            (f"tpo/ContinuousNavHeading-{name}-v0", "ContinuousNavEnv", {"action": "heading"}),
        ):
            if env_id not in gym.registry:
                # Gymnasium's passive checker expects scalar rewards; these are vectors.
                gym.register(env_id, entry_point=f"tpo.envs.gym_envs:{entry}",
                             kwargs={"map": name, **kwargs}, disable_env_checker=True)
            ids.append(env_id)
    if "tpo/RandomTMDP-v0" not in gym.registry:  # gym.make("tpo/RandomTMDP-v0", seed=3, ...)
        gym.register("tpo/RandomTMDP-v0", entry_point="tpo.envs.random_tmdp:random_gym_env",
                     disable_env_checker=True)
    return [*ids, "tpo/RandomTMDP-v0"]
