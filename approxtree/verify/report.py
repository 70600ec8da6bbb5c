"""VerifyReport: what ``approxtree verify`` found, check by check.

A *check* is one kind of claim (errors, completeness, checksums, bounding volumes, ...), run
over every node, tile, level or chunk of the output; it holds when every one of them does.
The ``offenders`` are the worst failures (the largest excess of measured over claimed first),
at most ``MAX_OFFENDERS`` per check; ``figures`` are the measurements (counts, worst ratios).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

#: Offenders kept per check (the worst ones).
MAX_OFFENDERS = 10

#: A claim holds when measured <= claimed × (1 + REL_SLACK) + abs slack (``claim_holds``).
REL_SLACK = 1e-9


def claim_holds(measured: float, claimed: float, abs_slack: float = 0.0) -> bool:
    """measured <= claimed × (1 + REL_SLACK) + abs_slack (inf claims hold anything)."""
    if math.isnan(measured):
        return True
    if math.isinf(claimed) and claimed > 0:
        return True
    return measured <= claimed * (1.0 + REL_SLACK) + abs_slack


def claims_hold(measured: np.ndarray, claimed: np.ndarray, abs_slack: float = 0.0) -> np.ndarray:
    """``claim_holds`` of arrays at once: (k,) bool."""
    measured = np.asarray(measured, dtype=np.float64)
    claimed = np.asarray(claimed, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        ok = measured <= claimed * (1.0 + REL_SLACK) + abs_slack
    return ok | np.isnan(measured) | (np.isinf(claimed) & (claimed > 0))


def _json(value: Any) -> Any:
    """JSON has no inf or NaN: they become the strings "inf", "-inf", "nan"."""
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, dict):
        return {k: _json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json(v) for v in value]
    return value


@dataclass
class Offender:
    """One failed claim: where (a node, tile, level, chunk), what was claimed and measured."""

    check: str
    address: str
    claimed: Any
    measured: Any
    #: Sort key: how far the claim is off (inf for a missing or undecodable part).
    excess: float = math.inf

    def to_dict(self) -> dict[str, Any]:
        return _json(
            {
                "check": self.check,
                "address": self.address,
                "claimed": self.claimed,
                "measured": self.measured,
            }
        )


@dataclass
class Check:
    """One kind of claim, over ``items`` parts of the output, ``failures`` of which failed."""

    name: str
    description: str
    items: int = 0
    failures: int = 0
    offenders: list[Offender] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.failures == 0

    def fail(self, address: str, claimed: Any, measured: Any, excess: float = math.inf) -> None:
        """Record one failed part."""
        self.failures += 1
        self.offenders.append(Offender(self.name, address, claimed, measured, float(excess)))
        if len(self.offenders) > 4 * MAX_OFFENDERS:
            self._trim()

    def _trim(self) -> None:
        self.offenders.sort(key=lambda o: -o.excess)
        del self.offenders[MAX_OFFENDERS:]

    def to_dict(self) -> dict[str, Any]:
        self._trim()
        return {
            "name": self.name,
            "description": self.description,
            "ok": self.ok,
            "items": self.items,
            "failures": self.failures,
            "offenders": [o.to_dict() for o in self.offenders],
        }


@dataclass
class VerifyReport:
    """The outcome of ``approxtree.verify``: kind of output, checks run, figures.

    kind: "tree-store", "mesh", "3dtiles", "quantized-mesh", "texture-pyramid", "raster-dem" or
    "imagery";
    not_checked: claims of the output that this verification could not recompute, and why.
    """

    kind: str
    output: str
    source: str | None
    checks: dict[str, Check] = field(default_factory=dict)
    figures: dict[str, Any] = field(default_factory=dict)
    not_checked: list[str] = field(default_factory=list)

    def check(self, name: str, description: str) -> Check:
        """The check ``name``, added on first use."""
        if name not in self.checks:
            self.checks[name] = Check(name, description)
        return self.checks[name]

    @property
    def ok(self) -> bool:
        """True when every claim checked holds."""
        return all(c.ok for c in self.checks.values())

    @property
    def offenders(self) -> list[Offender]:
        """The worst failures of every check, worst first."""
        out = []
        for c in self.checks.values():
            c._trim()
            out.extend(c.offenders)
        return sorted(out, key=lambda o: -o.excess)

    def to_dict(self) -> dict[str, Any]:
        """The report as JSON-ready data (``approxtree verify --json``)."""
        return {
            "kind": self.kind,
            "output": self.output,
            "source": self.source,
            "ok": self.ok,
            "checks": [c.to_dict() for c in self.checks.values()],
            "figures": _json(self.figures),
            "not_checked": list(self.not_checked),
        }
