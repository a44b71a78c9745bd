"""Query defense of paper Sec. 6: accept a pose only if its inliers spread over enough objects.

An instance *contributes* if it holds at least ``min_fraction`` of the inliers of the instance with most
inliers; the query is rejected if fewer than ``min_instances`` instances contribute.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, field

from synthleak.config import DefenseConfig


def contributing_instances(counts: Mapping[int, int], min_fraction: float) -> list[int]:
    """Instance ids with at least ``min_fraction`` of the top instance's inliers (background 0 excluded)."""
    counts = {int(k): int(v) for k, v in counts.items() if int(k) != 0 and int(v) > 0}
    if not counts:
        return []
    top = max(counts.values())
    return sorted(k for k, v in counts.items() if v >= min_fraction * top)


def decide(counts: Mapping[int, int], min_fraction: float, min_instances: int) -> bool:
    """True if the query is accepted (offline sweeps call this on logged counts)."""
    return len(contributing_instances(counts, min_fraction)) >= min_instances


@dataclass(frozen=True)
class DefenseDecision:
    """One logged decision with the counts it was made from."""

    accepted: bool
    min_fraction: float
    min_instances: int
    contributing: list[int]
    counts: dict[int, int] = field(default_factory=dict)

    def to_json(self) -> dict:
        data = asdict(self)
        data["counts"] = {str(k): v for k, v in self.counts.items()}
        return data


@dataclass(frozen=True)
class DefensePolicy:
    """Sec. 6 defense; disabled by default (then :meth:`apply` still reports what it would decide)."""

    min_fraction: float = 0.1
    min_instances: int = 3
    enabled: bool = False

    def __post_init__(self) -> None:
        if not 0.0 <= self.min_fraction <= 1.0:
            raise ValueError(f"DefensePolicy.min_fraction must be in [0, 1], got {self.min_fraction}")
        if self.min_instances < 0:
            raise ValueError(f"DefensePolicy.min_instances must be >= 0, got {self.min_instances}")

    @classmethod
    def from_config(cls, config: DefenseConfig) -> DefensePolicy:
        """The policy of a study's ``[defense]`` table."""
        return cls(config.min_fraction, config.min_instances, config.enabled)

    def apply(self, counts: Mapping[int, int]) -> DefenseDecision:
        contributing = contributing_instances(counts, self.min_fraction)
        return DefenseDecision(
            accepted=len(contributing) >= self.min_instances,
            min_fraction=self.min_fraction,
            min_instances=self.min_instances,
            contributing=contributing,
            counts={int(k): int(v) for k, v in sorted(counts.items())},
        )
