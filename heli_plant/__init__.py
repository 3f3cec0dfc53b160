"""The plant: the 6-DOF model, its integrator and ground contact (``model``), and the plant
process's server with its servo inputs (``server``, ``can_endpoint``). Never imports the
autopilot: it sees the controller only as commands on a link."""

import heli_common  # noqa: F401  (first: one BLAS thread, before numpy loads)
