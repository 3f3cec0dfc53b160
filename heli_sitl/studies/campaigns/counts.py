"""How a campaign's flights ended, counted once: the one reader of the rows' outcome flags.

Three outcomes are kept apart everywhere (the table, campaign.json, the figures, the exit
status): a flight that **failed** raised an error and has no metrics (the bench's fault, or
a user's controller code); a flight that **diverged** was flown and lost (tumbled, ran away,
state blew up); a flight flown and not lost either **converged** (within ``converge_m``) or
did not.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pyarrow as pa

from heli_sitl.studies.stats import Interval, loss_rate


def flags(table: pa.Table, name: str) -> np.ndarray:
    """A 0/1 column as booleans (all False where the campaign did not ask for it)."""
    if name not in table.column_names:
        return np.zeros(table.num_rows, bool)
    return np.array([bool(v) for v in table.column(name).to_pylist()])


def outcomes(table: pa.Table) -> dict[str, np.ndarray]:
    """Each flight's one outcome: failed (raised, no metrics), else diverged (lost), else
    converged, else not converged (where the rows have no converged flag: every flight
    flown and not lost counts as converged)."""
    failed = flags(table, "failed")
    div = flags(table, "diverged") & ~failed
    conv = (flags(table, "converged") if "converged" in table.column_names else ~div) & ~failed & ~div
    return {"converged": conv, "not_converged": ~failed & ~div & ~conv, "diverged": div, "failed": failed}


@dataclass(frozen=True)
class CampaignCounts:
    flights: int
    failed: int  # raised an error: no metrics
    converged: int | None = None  # flown, not failed, within converge_m (None: not measured)
    diverged: int | None = None  # flown and lost (None: not measured)
    diverged_by_reason: dict[str, int] = field(default_factory=dict)
    # diverged of the flights flown (failed ones are not flights of the controller)
    loss_rate: Interval | None = None

    @property
    def flown(self) -> int:
        return self.flights - self.failed

    @property
    def not_converged(self) -> int | None:
        """Flown, not lost, and never within converge_m."""
        if self.converged is None or self.diverged is None:
            return None
        return self.flown - self.converged - self.diverged

    @classmethod
    def of(cls, table: pa.Table, sampled: bool = True) -> CampaignCounts:
        """The counts of a campaign's rows. ``sampled``: the flights are a random sample
        of what could be flown, so their loss rate estimates a probability and carries its
        interval; a grid's (``sampler = "grid"``) is a fact of the grid, given bare."""
        o = outcomes(table)
        failed, div = o["failed"], o["diverged"]
        n = int(table.num_rows)
        converged = diverged = None
        reasons: dict[str, int] = {}
        rate = None
        if "converged" in table.column_names:
            converged = int(o["converged"].sum())
        if "diverged" in table.column_names:
            diverged = int(div.sum())
            if "diverged_reason" in table.column_names:
                # by kind: a reason's text before its particulars ("tilt > 60 deg (61 deg at t = ...)")
                why = [str(r).split(" (")[0] for r, d in zip(table.column("diverged_reason").to_pylist(), div,
                                                              strict=True) if d]  # fmt: skip
                reasons = {r: why.count(r) for r in sorted(set(why))}
            flown = n - int(failed.sum())
            if flown > 0 and sampled:
                rate = loss_rate(diverged, flown)
        return cls(n, int(failed.sum()), converged, diverged, reasons, rate)

    def as_dict(self) -> dict[str, Any]:
        """campaign.json's ``counts`` (keys present only where measured)."""
        out: dict[str, Any] = {"flights": self.flights, "failed": self.failed}
        if self.converged is not None:
            out["converged"] = self.converged
        if self.diverged is not None:
            out["diverged"] = self.diverged
            if self.diverged_by_reason:
                out["diverged_by_reason"] = dict(self.diverged_by_reason)
            if self.not_converged is not None:
                out["not_converged"] = self.not_converged
            if self.loss_rate is not None:
                out["loss_rate"] = {"estimate": self.loss_rate.estimate,
                                    "ci95": [self.loss_rate.lo, self.loss_rate.hi]}  # fmt: skip
        return out

    def line(self) -> str:
        """The one-line account the table ends with."""
        parts = [f"flights {self.flights}", f"failed (raised) {self.failed}"]
        if self.converged is not None:
            parts.append(f"converged {self.converged}")
        if self.not_converged is not None:
            parts.append(f"flown but not converged {self.not_converged}")
        text = ", ".join(parts)
        if self.diverged is not None:
            why = "; ".join(f"{k}: {v}" for k, v in self.diverged_by_reason.items())
            text += f", diverged {self.diverged}" + (f" ({why})" if why else "")
        if self.loss_rate is not None:
            lr = self.loss_rate
            text += (f"; loss rate {100 * lr.estimate:.2f} % [{100 * lr.lo:.2f}, {100 * lr.hi:.2f}] % "
                     "(95 %, exact)")  # fmt: skip
        elif self.diverged is not None and self.flown > 0:  # a grid: the share of its points
            share = 100 * self.diverged / self.flown
            text += f"; lost at {share:.2f} % of the grid's points (a map: no interval)"
        return text
