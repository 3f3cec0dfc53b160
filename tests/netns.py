"""Private network namespaces for tests that need udp_multicast (never the host's network)."""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
import sys

# what the namespace's shell does first: loopback up, the IPv4 multicast range routed on it
NETNS_SETUP = "ip link set lo up && ip route add 224.0.0.0/4 dev lo"


def unshare_reason() -> str | None:
    """Why a test cannot make its own network namespace here, or None if it can."""
    if not sys.platform.startswith("linux"):
        return "network namespaces are Linux-only"
    if shutil.which("unshare") is None or shutil.which("ip") is None:
        return "needs unshare (util-linux) and ip (iproute2)"
    if importlib.util.find_spec("msgpack") is None:
        return "python-can's udp_multicast needs msgpack (pip install 'python-can[multicast]')"
    probe = subprocess.run(["unshare", "--net", "true"], capture_output=True, timeout=10)
    if probe.returncode != 0:
        return f"cannot make a network namespace (unshare --net: {probe.stderr.decode().strip()})"
    return None


def skip_without_firmware_netns() -> None:
    """Skip the calling test, saying why, where ArduPilot's SITL binary is missing or no
    private network namespace can be made (its TCP 5760-5763 and UDP 9002 stay in one)."""
    import pytest

    from heli_sitl.launch.ardupilot import FirmwareNotFoundError, find_firmware

    try:
        find_firmware(None)
    except FirmwareNotFoundError as exc:
        pytest.skip(f"ArduPilot's SITL binary is not here: {exc}")
    why = unshare_reason()
    if why is not None and "msgpack" not in why:  # (msgpack is python-can's, not needed here)
        pytest.skip(why)
