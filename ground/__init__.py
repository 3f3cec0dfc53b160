"""ground: the ground-station side: upload, command, log telemetry, plot."""
