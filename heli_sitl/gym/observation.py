"""The environments' observation, named once: ``observation_names(action_mode)`` labels each
element of :data:`heli_sitl.engine.batch.OBS` (the compiled layout it is filled in)."""

from __future__ import annotations

from heli_common.state import PITCH_NAMES, STATE_NAMES
from heli_sitl.engine.batch import N_OBS, OBS

_AXES = ("x", "y", "z")
_COMMAND = {True: "base", False: "last"}  # residual mode: the law's; pitch mode: the last action


def observation_names(action_mode: str) -> tuple[str, ...]:
    """Each observation element's name, in order: the measured state (the plant's layout:
    earth NWU position, body FLU velocity, ZYX Euler angles, body FLU rates; the estimate
    when the world's sensors are on), the position and velocity errors (measured minus
    reference, earth NWU; 0 where the reference has no velocity), the reference's
    acceleration (earth NWU; 0 where unknown), and the command block: in residual mode the
    built-in law's command this tick (``base_*_norm``), in pitch mode the previous action
    (``last_*_norm``), both as [-1, 1] of the pitch limits."""
    blocks = {
        "state": STATE_NAMES,
        "pos_err_nwu_m": tuple(f"{a}_err_nwu_m" for a in _AXES),
        "vel_err_nwu_m_s": tuple(f"v{a}_err_nwu_m_s" for a in _AXES),
        "acc_ref_nwu_m_s2": tuple(f"a{a}_ref_nwu_m_s2" for a in _AXES),
        "command_norm": tuple(f"{_COMMAND[action_mode == 'residual']}_{p}_norm" for p in PITCH_NAMES),
    }
    names = tuple(n for block in OBS.names for n in blocks[block])
    assert len(names) == N_OBS and all(len(blocks[b]) == OBS.size_of(b) for b in OBS.names)
    return names
