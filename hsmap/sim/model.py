"""The scenario model: the walls, doors, rooms, furniture, route and sensors of a simulated world
(:class:`Scenario`), as :func:`hsmap.sim.scenario.load_scenario` reads them from a file."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .robot import OdometryConfig, RobotConfig, RouteStep
from .sensors import Lidar2DConfig, Lidar3DConfig

__all__ = ["Wall", "Door", "Room", "Furniture", "Scenario", "FURNITURE_TYPES"]


# type -> (default footprint size (lx, ly), default height); the parts are built in hsmap.sim.layout
FURNITURE_TYPES: dict[str, tuple[tuple[float, float] | None, float | None]] = {
    "table": ((1.6, 0.8), 0.75),  # top on four legs
    "desk": ((1.4, 0.7), 0.75),  # top on two side panels, with a modesty panel at the back (-y side)
    "chair": ((0.5, 0.5), 0.9),  # seat on four legs, backrest on the -x side (the chair faces +x)
    "shelf": ((1.0, 0.4), 1.9),  # solid
    "cabinet": ((0.8, 0.5), 1.1),  # solid
    "counter": ((2.0, 0.6), 0.9),  # solid
    "sofa": ((2.0, 0.9), 0.8),  # seat block with a backrest on the -y side
    "column": ((0.4, 0.4), None),  # solid, floor to ceiling by default
    "box": (None, None),  # solid, size and height required
}


@dataclass
class Wall:
    """A straight wall between two points (its centre line), extended by half its thickness at both ends."""

    index: int
    name: str
    start: NDArray[np.float64]
    end: NDArray[np.float64]
    thickness: float
    height: float

    @property
    def where(self) -> str:
        return f"walls[{self.index}]" + (f" '{self.name}'" if self.name else "")

    @property
    def length(self) -> float:
        return float(np.hypot(*(self.end - self.start)))

    @property
    def direction(self) -> NDArray[np.float64]:
        return (self.end - self.start) / self.length

    @property
    def normal(self) -> NDArray[np.float64]:
        u = self.direction
        return np.array([-u[1], u[0]])

    @property
    def yaw(self) -> float:
        u = self.direction
        return float(np.arctan2(u[1], u[0]))


@dataclass
class Door:
    """A door opening in a wall, centred ``at`` metres from the wall's start point."""

    index: int
    name: str
    wall: int
    at: float
    width: float
    height: float
    open: bool

    @property
    def where(self) -> str:
        return f"doors[{self.index}]" + (f" '{self.name}'" if self.name else "")


@dataclass
class Room:
    """A named region (room or corridor) bounded by a polygon, usually through the wall centre lines."""

    index: int
    name: str
    polygon: NDArray[np.float64]  # (K, 2)

    @property
    def label(self) -> int:
        return self.index + 1


@dataclass
class Furniture:
    """A piece of furniture: its footprint box, height and type (see :data:`FURNITURE_TYPES`)."""

    index: int
    type: str
    name: str
    center: NDArray[np.float64]
    size: NDArray[np.float64]
    yaw: float
    height: float

    @property
    def where(self) -> str:
        return f"furniture[{self.index}] ({self.type}" + (f" '{self.name}')" if self.name else ")")


@dataclass
class Scenario:
    """A parsed and checked scenario (see :func:`load_scenario`)."""

    name: str
    description: str = ""
    path: str = ""
    sha256: str = ""
    seed: int = 0
    frame_rate: float = 2.0
    start_time: float = 0.0
    wall_height: float = 2.8
    ceiling_height: float | None = 2.8
    label_resolution: float = 0.05
    walls: list[Wall] = field(default_factory=list)
    doors: list[Door] = field(default_factory=list)
    rooms: list[Room] = field(default_factory=list)
    furniture: list[Furniture] = field(default_factory=list)
    start: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    steps: list[RouteStep] = field(default_factory=list)
    robot: RobotConfig = field(default_factory=RobotConfig)
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    lidar2d: Lidar2DConfig = field(default_factory=Lidar2DConfig)
    lidar3d: Lidar3DConfig = field(default_factory=Lidar3DConfig)
    raw: dict = field(default_factory=dict)

    def replace(self, **changes: Any) -> Scenario:
        """A copy with some fields changed (e.g. smaller sensors for a quick run); not re-validated.

        The copy no longer matches its file, so its ``sha256`` is cleared.
        """
        changes.setdefault("sha256", "")
        return dataclasses.replace(self, **changes)

    def wall(self, ref: int) -> Wall:
        return self.walls[ref]
