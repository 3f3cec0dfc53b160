"""One context-manager protocol for everything that owns a socket or a bus."""

from __future__ import annotations

from types import TracebackType
from typing import Self


class Closing:
    """``with X(...) as x:`` calls ``x.close()`` on the way out, whatever happens."""

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
