"""``dyno doctor``'s report: one line per check, and the verdict (:mod:`dyno.hw.doctor`)."""

from __future__ import annotations

from dataclasses import dataclass, field

OK, WARN, FAIL, SKIP = "ok", "warn", "FAIL", "skip"


@dataclass
class Check:
    name: str
    status: str
    detail: str
    essential: bool = True


@dataclass
class Report:
    checks: list[Check] = field(default_factory=list)

    def add(self, name, status, detail, essential=True) -> Check:
        c = Check(name, status, detail, essential)
        self.checks.append(c)
        return c

    @property
    def ok(self) -> bool:
        return not any(c.status == FAIL and c.essential for c in self.checks)

    def render(self) -> str:
        width = max((len(c.name) for c in self.checks), default=0)
        lines = [f"  {c.status:>4}  {c.name:<{width}}  {c.detail}" for c in self.checks]
        verdict = "rig OK" if self.ok else "rig NOT ready: fix the FAIL lines above"
        return "\n".join(lines + ["", verdict])
