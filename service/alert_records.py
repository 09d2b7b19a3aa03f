"""An engine's alert records: what an alert is (its contract's shape, its acknowledgements) and the events the alert
engine (service.alerts) returns; no decision logic here."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields, replace

__all__ = ["RULE_OF_KIND", "Alert", "AlertEvent", "snapshot"]

@dataclass
class Alert:
    """One alert (the contract's shape; ``to_dict`` without engine_id: the service adds it). 1-based cylinder.

    ``acknowledged_by`` is the first person who acknowledged it (kept); ``acknowledgements`` every acknowledgement
    in order, {by, at_s (wall-clock Unix s), cycle}. ``rule`` names the rule that raised it (the key an alert
    restored from the store is found under again)."""

    alert_id: int
    cylinder: int | None
    kind: str
    severity: str
    state: str
    raised_cycle: int
    raised_at_s: float
    message: str
    evidence: dict = field(default_factory=dict)
    cleared_cycle: int | None = None
    acknowledged_by: str | None = None
    acknowledgements: list = field(default_factory=list)
    rule: str | None = None

    def to_dict(self) -> dict:
        d = asdict(self)
        d["evidence"] = dict(self.evidence)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> Alert:
        """An alert from ``to_dict`` output (extra keys such as engine_id ignored); ValueError (one line) otherwise."""
        names = {f.name for f in fields(cls)}
        try:
            a = cls(**{k: v for k, v in d.items() if k in names})
            a.alert_id, a.raised_cycle = int(a.alert_id), int(a.raised_cycle)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"not an alert: {exc}") from None
        if a.state not in ("active", "acknowledged", "cleared") or a.severity not in ("info", "warning", "alarm"):
            raise ValueError(f"alert {a.alert_id}: state {a.state!r} / severity {a.severity!r} not known")
        a.evidence, a.acknowledgements = dict(a.evidence or {}), list(a.acknowledgements or [])
        return a


@dataclass(frozen=True)
class AlertEvent:
    """kind: raised | updated | cleared; alert: a snapshot at the event (later changes do not reach it)."""

    kind: str
    alert: Alert


def snapshot(a: Alert) -> Alert:
    """A copy whose evidence and acknowledgements later changes to ``a`` do not reach."""
    return replace(a, evidence=dict(a.evidence), acknowledgements=[dict(x) for x in a.acknowledgements])


# the rule that raises each kind, for an alert stored before alerts named their rule (a guess: ring_wear and
# blow_by may also come from the core's flags before a baseline; the guessed rule then clears it when its own
# evidence is absent)
RULE_OF_KIND = {"ring_wear": "friction", "blow_by": "leak", "misfire": "misfire", "sensor_fault": "sensor_fault",
                "model_misfit": "model_misfit"}
