"""Gymnasium environments of the bench: ``HeliSitl/Track-v0`` and its vectorised form.

Importing this package registers the id (``gymnasium.make("HeliSitl/Track-v0")``,
``gymnasium.make_vec(..., vectorization_mode="vector_entry_point")``); without importing it
first, name the module in the id: ``gymnasium.make("heli_sitl.gym:HeliSitl/Track-v0")``.
The environments' modules load on first use. A policy trained here flies as a controller
everywhere the bench flies one: :mod:`heli_sitl.gym.policy`. Guide: docs/gym.md.
"""

from __future__ import annotations

import gymnasium

ENV_ID = "HeliSitl/Track-v0"

if ENV_ID not in gymnasium.registry:
    gymnasium.register(
        id=ENV_ID,
        entry_point="heli_sitl.gym.env:HeliTrackEnv",
        vector_entry_point="heli_sitl.gym.vector:HeliTrackVectorEnv",
    )

__all__ = ["ENV_ID"]
