"""Rate-limited logging for faults that can repeat at the control rate."""

from __future__ import annotations

import logging


class RateLimitedLog:
    """Logs each kind of event at most once per ``interval_s`` of the caller's time.

    A fault repeating at the control rate (a dead bus at 100 Hz) would otherwise flood the
    log; the line carries the running count, so nothing is hidden. Time is passed in:
    link code reads no clock.
    """

    def __init__(self, logger: logging.Logger, interval_s: float = 1.0) -> None:
        self.logger = logger
        self.interval_s = interval_s
        self._last_s: dict[str, float] = {}
        self._seen: set[str] = set()

    def __call__(
        self, level: int, kind: str, now_s: float, msg: str, *args: object, exc_info: bool = False
    ) -> bool:
        """Log unless ``kind`` was logged less than ``interval_s`` ago; ``exc_info`` adds
        the traceback only the first time a kind is seen."""
        last = self._last_s.get(kind)
        if last is not None and abs(now_s - last) < self.interval_s:
            return False
        self._last_s[kind] = now_s
        self.logger.log(level, msg, *args, stacklevel=2,  # report the caller's line
                        exc_info=exc_info and kind not in self._seen)  # fmt: skip
        self._seen.add(kind)
        return True
