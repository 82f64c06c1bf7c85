"""What became of one notebook of the batch (:class:`NotebookRun`, ``reports/NAME/run.json``)."""

from __future__ import annotations

import datetime as dt
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

__all__ = ["NotebookRun", "now_text"]


@dataclass
class NotebookRun:
    """What became of one notebook (also written as ``reports/NAME/run.json``)."""

    name: str
    notebook: str
    title: str = ""
    status: str = "not run"  # "ok", "skipped", "failed", "running", "pending", "not run", "interrupted"
    error: str | None = None
    error_cell: int | None = None
    started: str | None = None
    duration_s: float | None = None
    parameters: dict[str, Any] = field(default_factory=dict)
    html: str | None = None
    ipynb: str | None = None
    figures: list[str] = field(default_factory=list)
    recordings: list[str] = field(default_factory=list)
    metrics: dict[str, Any] | None = None
    warnings: list[str] = field(default_factory=list)
    pid: int | None = None  # of the batch that has it pending or running (a dead one's entry is stale)

    @property
    def ok(self) -> bool:
        """Ran through: "ok", or "skipped" (its inputs are missing, and it said so)."""
        return self.status in ("ok", "skipped")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> NotebookRun:
        known = {f for f in cls.__dataclass_fields__}
        return cls(**{k: v for k, v in d.items() if k in known})


def now_text() -> str:
    return dt.datetime.now().astimezone().isoformat(timespec="seconds")
