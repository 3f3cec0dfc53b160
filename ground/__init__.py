"""ground: the ground-station side: upload, command, log telemetry, plot."""

import heli_common  # noqa: F401  (first: one BLAS thread, before numpy loads)
