"""What validation produces: one bag's scan, its verdict, and a whole run's (shared by validate and the report)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from roi_node import __version__
from roi_node.bagio.bag_status import STATUS_KEY
from roi_node.bagio.reader import TopicStats
from roi_node.engine.metadata import METADATA_SCHEMA
from roi_node.quality.gates import GateResult, GateSet
from roi_node.quality.roibag import RoiBag
from roi_node.quality.samples import Sample
from roi_node.quality.stats import BagStats, BagSummary
from roi_node.quality.validation_records import BagResult, ValidationFormatError

VALIDATION_SCHEMA = "roi_node/validation/v1"


@dataclass
class BagScan:
    """What one pass over a bag yields: its topics, bag information, statistics and samples."""

    path: Path
    topics: dict[str, TopicStats]
    information: dict[str, Any]
    start_ns: int
    end_ns: int
    summary: BagSummary
    samples: list[Sample]
    camera: str | None = None  # the camera of a bag of several (its outputs under /roi/<camera>/); None: a rig of one

    @classmethod
    def of(cls, path: Path, bag: RoiBag, stats: BagStats, samples: list[Sample]) -> BagScan:
        """The scan of a bag whose records `stats` has seen (the recorded status finishes its summary)."""
        return cls(
            camera=bag.camera,
            path=path,
            topics=bag.topics,
            information=bag.information,
            start_ns=bag.start_ns,
            end_ns=bag.end_ns,
            summary=stats.finish((bag.information.get("custom_data") or {}).get(STATUS_KEY)),
            samples=samples,
        )


@dataclass
class BagValidation:
    """The verdict on one bag: what validation found (`result`) and its gates (the per-frame series are not kept)."""

    path: Path
    name: str
    gates: list[GateResult]
    result: BagResult
    figures: dict[str, str] = field(default_factory=dict)

    @property
    def failed(self) -> list[GateResult]:
        return [g for g in self.gates if g.failed]

    def as_dict(self) -> dict[str, Any]:
        gates = [g.as_dict() for g in self.gates]
        return {**self.result.as_dict(), "passed": not self.failed, "gates": gates, "figures": dict(self.figures)}

    @classmethod
    def from_dict(cls, doc: Any) -> BagValidation:
        """A `bags[]` entry of validation.json; `passed` is not read, the gates' statuses decide it."""
        result = BagResult.from_dict(doc)
        try:
            gates = [GateResult.from_dict(g) for g in doc["gates"]]
            figures = dict(doc["figures"])
        except KeyError as exc:
            raise ValidationFormatError(str(exc.args[0]), "missing") from exc
        except (TypeError, AttributeError, ValueError) as exc:
            raise ValidationFormatError("gates", f"of the wrong shape ({exc})") from exc
        return cls(Path(result.path), result.name, gates, result, figures)


@dataclass
class ValidationRun:
    gates: GateSet
    baseline: Path | None
    bags: list[BagValidation]

    @property
    def passed(self) -> bool:
        return not any(b.failed for b in self.bags)

    def as_dict(self) -> dict[str, Any]:
        return {
            "schema": VALIDATION_SCHEMA,
            "roi_node_version": __version__,
            "metadata_schema": METADATA_SCHEMA,
            "gates": {
                "path": str(self.gates.path),
                "sha256": self.gates.sha256,
                "params": asdict(self.gates.params),
                "thresholds": [{"gate": g.metric, "scope": g.scope, "op": g.op, "threshold": g.threshold} for g in self.gates.gates],
            },
            "baseline": None if self.baseline is None else str(self.baseline),
            "passed": self.passed,
            "bags": [b.as_dict() for b in self.bags],
        }
