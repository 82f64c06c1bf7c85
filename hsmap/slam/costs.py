"""What a HS-SLAM run did, counted (:class:`Costs`): a measure of its work that no clock or core count changes."""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

__all__ = ["Costs"]


@dataclass
class Costs:
    """Counts of a run's costly steps, the same for the same input, configuration and seed.

    Attributes
    ----------
    registrations : int
        Harmony-ICP registrations (:func:`hsmap.registration.icp.harmony_icp`): tracking, its retries, loop searches.
    refinements : int
        Local refinements outside them (:func:`hsmap.registration.icp.refine_icp`): pair edges, the smoothing's
        scan-to-scan matches.
    harmony_evaluations : int
        Candidate poses the registrations' Harmony Searches scored.
    retries : int
        Tracking registrations retried around the motion prediction (counted in ``registrations`` too).
    full_searches : int
        Tracking registrations searched in the full box after a search in the tight box of the prediction's
        uncertainty that its result escaped (:meth:`hsmap.slam.search.SearchBox.escapes`; both counted in
        ``registrations``).
    loop_searches : int
        Near loop-closure searches (one registration each).
    far_searches : int
        Far loop-closure searches (an exhaustive correlative match and a registration each).
    optimizations : int
        Pose-graph optimisations.
    optimization_rounds : int
        Their Levenberg-Marquardt runs (an optimisation reruns after switching edges off).
    optimization_iterations : int
        The iterations of those runs.
    map_rebuilds : int
        Tracking maps rebuilt from the keyframes.
    points_inserted : int
        Points inserted into the tracking map: each keyframe's, and every rebuild's.
    """

    registrations: int = 0
    refinements: int = 0
    harmony_evaluations: int = 0
    retries: int = 0
    full_searches: int = 0
    loop_searches: int = 0
    far_searches: int = 0
    optimizations: int = 0
    optimization_rounds: int = 0
    optimization_iterations: int = 0
    map_rebuilds: int = 0
    points_inserted: int = 0

    def add(self, **counts: int) -> None:
        """Add ``counts`` (field name: amount, >= 0) to the counters."""
        for name, n in counts.items():
            if name not in self.__dataclass_fields__:
                raise AttributeError(f"Costs has no counter {name!r}; expected one of {self.names()}")
            if n < 0:
                raise ValueError(f"Costs.{name}: a count only grows, got {n}")
            setattr(self, name, getattr(self, name) + int(n))

    def registration(self, evaluations: int) -> None:
        """One Harmony-ICP registration that scored ``evaluations`` candidate poses."""
        self.add(registrations=1, harmony_evaluations=evaluations)

    def as_dict(self) -> dict[str, int]:
        """The counters by name (JSON-ready)."""
        return {k: int(v) for k, v in asdict(self).items()}

    @classmethod
    def names(cls) -> list[str]:
        """The counters' names, in order."""
        return [f.name for f in fields(cls)]
