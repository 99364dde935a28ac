"""Gymnasium registration of the training environment.

``import sanav_mj`` calls :func:`register_envs` when gymnasium is installed, so

    import gymnasium, sanav_mj
    env = gymnasium.make("sanav_mj/Nav-v0", render_mode="rgb_array")

builds a :class:`sanav_mj.sim.nav_env.NavEnv` (keyword arguments go to its constructor:
``config``, ``map_factory``, ``render_mode``). Registration imports only
``gymnasium.envs.registration``; the environment module (MuJoCo) is imported by ``make``,
and torch never (it is needed for training only).
"""

from __future__ import annotations

import importlib.util

#: gymnasium id of :class:`sanav_mj.sim.nav_env.NavEnv`
NAV_ENV_ID = "sanav_mj/Nav-v0"


def register_envs() -> bool:
    """Register :data:`NAV_ENV_ID` with gymnasium (once).

    Returns:
        True when it is registered, False when gymnasium is not installed.
    """
    if importlib.util.find_spec("gymnasium") is None:
        return False
    from gymnasium.envs.registration import register, registry

    if NAV_ENV_ID not in registry:
        # The environment has its own timeout (TerminationConfig.time_limit_s): no TimeLimit wrapper.
        register(id=NAV_ENV_ID, entry_point="sanav_mj.sim.nav_env:NavEnv")
    return True
