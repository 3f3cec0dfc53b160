"""What every command-line tool does the same way: signals, errors, exit status."""

from __future__ import annotations

import signal
import sys
import threading
from collections.abc import Callable
from types import FrameType

from heli_common.config import ConfigError
from heli_common.defaults import Exit
from heli_common.wire.mavlink.udp import PortBusyError
from heli_common.wire.mavlink.wire import SigningKeyError


class UsageError(ValueError):
    """Options that cannot work together (a one-line usage error, exit status 2)."""


def terminate_on_sigterm() -> None:
    """Turn SIGTERM into KeyboardInterrupt, so ``finally`` blocks stop the children."""

    def raise_interrupt(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, raise_interrupt)


def stop_on_signals(stop: threading.Event) -> None:
    """SIGTERM and SIGINT set ``stop``, from a thread of their own. A handler runs in the main
    thread between two bytecodes, possibly inside ``stop.wait()`` while that holds the event's
    lock: ``stop.set()`` in the handler then waits for the lock its own thread holds, forever
    (seen: a plant on the ground deaf to SIGTERM for 40 minutes, orphaned by its launcher).
    The thread takes the lock once the main thread lets go of it."""

    def on_signal(signum: int, frame: FrameType | None) -> None:
        threading.Thread(target=stop.set, name="stop-on-signal", daemon=True).start()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)


def run_main(
    prog: str,
    body: Callable[[], int],
    *,
    usage: tuple[type[BaseException], ...] = (),
    failure: tuple[type[BaseException], ...] = (),
    port_hint: str = "",
) -> int:
    """Run a command's ``body`` and turn what it raises into one line on stderr and the
    exit status every command shares (:class:`heli_common.defaults.Exit`): ``usage``
    errors (and config and signing-key errors) are bad input, ``failure`` ones a vehicle,
    link or child failure, a busy port its own status, Ctrl-C 130."""
    usage_errors: tuple[type[BaseException], ...] = (SigningKeyError, UsageError, *usage)
    try:
        return body()
    except PortBusyError as exc:
        print(f"{prog}: {exc.strerror}{port_hint}", file=sys.stderr)
        return Exit.PORT_BUSY
    except ConfigError as exc:
        print(f"{prog}: config error: {exc}", file=sys.stderr)
        return Exit.USAGE
    except usage_errors as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return Exit.USAGE
    except failure as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return Exit.FAILURE
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return Exit.INTERRUPTED
