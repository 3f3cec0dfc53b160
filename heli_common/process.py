"""What every command-line tool does the same way: signals, errors, exit status."""

from __future__ import annotations

import signal
import sys
from collections.abc import Callable

from heli_common.config import ConfigError
from heli_common.defaults import Exit
from heli_common.mavlink.udp import PortBusyError
from heli_common.mavlink.wire import SigningKeyError


class UsageError(ValueError):
    """Options that cannot work together (a one-line usage error, exit status 2)."""


def terminate_on_sigterm() -> None:
    """Turn SIGTERM into KeyboardInterrupt, so ``finally`` blocks stop the children."""

    def raise_interrupt(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, raise_interrupt)


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
