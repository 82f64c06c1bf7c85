"""Occupancy grids, room labels, the 2D map view and the room/door graph in a rerun recording."""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

os.environ["RERUN_ANALYTICS"] = "0"  # before rerun is imported: never phone home from our runs

import numpy as np  # noqa: E402
import rerun as rr  # noqa: E402
from numpy.typing import ArrayLike, NDArray  # noqa: E402

from ..errors import InputError, ShapeError  # noqa: E402
from ..maps.grid import GridGeometry  # noqa: E402
from .colors import ROOM_PALETTE, VIEWER_SERIES_COLORS, label_color, label_colors  # noqa: E402
from .occupancy import _ros_to_image, occupancy_to_ros  # noqa: E402
from .rerun_core import (  # noqa: E402
    _UNIX_TIME_THRESHOLD,
    GRAPH,
    MAP2D,
    ROBOT_COLOR,
    WORLD_MAP,
    _path_positions,
    _points,
    _pose6,
    _stream,
)

__all__ = ["log_rgba_grid", "log_map2d_robot", "log_map2d_robots", "log_map2d_points", "log_occupancy_grid", "room_annotation_context", "log_room_labels", "world_to_map2d", "log_map2d_path", "log_room_graph"]

# --- grids and labels ----------------------------------------------------------------------------------


def _check_geometry(geometry: GridGeometry, shape: tuple[int, ...], what: str) -> None:
    if not isinstance(geometry, GridGeometry):
        raise InputError(f"geometry must be an hsmap.maps.grid.GridGeometry, got {type(geometry).__name__}")
    if tuple(shape[:2]) != geometry.shape:
        raise ShapeError(f"{what} has shape {tuple(shape[:2])} but its GridGeometry says {geometry.shape}")


def log_occupancy_grid(
    rec: Any,
    grid: ArrayLike,
    geometry: GridGeometry,
    *,
    convention: str = "auto",
    entity: str = f"{WORLD_MAP}/occupancy",
    map_entity: str | None = f"{MAP2D}/occupancy",
    z: float = 0.0,
    opacity: float | None = None,
    static: bool = True,
) -> None:
    """Log an occupancy grid: a ``GridMap`` in the 3D world where ``geometry`` places it, and an ``Image``
    in the 2D map view (``map_entity``; None to skip). See :func:`occupancy_to_ros` for ``convention``."""
    ros = occupancy_to_ros(grid, convention)
    _check_geometry(geometry, ros.shape, "occupancy grid")
    h, w = ros.shape
    s = _stream(rec)
    s.log(
        entity,
        rr.GridMap(
            data=np.ascontiguousarray(ros).tobytes(),
            format=rr.components.ImageFormat(width=w, height=h, color_model="L", channel_datatype="U8"),
            cell_size=geometry.resolution,
            translation=[geometry.origin[0], geometry.origin[1], z],
            colormap=rr.components.Colormap.RvizMap,
            opacity=opacity,
        ),
        static=static,
        strict=True,
    )
    if map_entity is not None:
        img = _ros_to_image(ros)
        s.log(map_entity, rr.Image(img, color_model="L", draw_order=-10.0), static=static, strict=True)


def room_annotation_context(
    ids: Iterable[int], names: Mapping[int, str] | None = None, *, background: str = "no room"
) -> rr.AnnotationContext:
    """One class per room id (its palette colour and name; "room k" by default); 0 is transparent."""
    infos = [rr.AnnotationInfo(0, background, (0, 0, 0, 0))]
    for k in sorted({int(i) for i in ids if int(i) > 0}):
        name = (names or {}).get(k, f"room {k}")
        infos.append(rr.AnnotationInfo(k, str(name), label_color(k)))
    return rr.AnnotationContext(infos)


def log_room_labels(
    rec: Any,
    labels: ArrayLike,
    geometry: GridGeometry,
    *,
    names: Mapping[int, str] | None = None,
    entity: str = f"{WORLD_MAP}/rooms",
    map_entity: str | None = f"{MAP2D}/rooms",
    z: float = 0.02,
    opacity: float = 0.6,
    static: bool = True,
) -> None:
    """Log a room label image (H, W) (0 = no room): in the 2D map view as ``SegmentationImage`` with an
    ``AnnotationContext`` (room names and colours), and in the 3D world as a coloured quad
    (:func:`log_rgba_grid`) placed by ``geometry`` just above the occupancy grid."""
    lab = np.asarray(labels)
    if lab.ndim != 2:
        raise ShapeError(f"labels must be an (H, W) image, got shape {lab.shape}")
    _check_geometry(geometry, lab.shape, "label image")
    if lab.size and (lab.min() < 0 or lab.max() > np.iinfo(np.uint16).max):
        raise InputError("labels must lie in 0..65535 (0 = no room)")
    lab16 = lab.astype(np.uint16)
    ids = np.unique(lab16)
    s = _stream(rec)
    rgba = label_colors(lab16)
    rgba[..., 3] = np.where(rgba[..., 3] > 0, int(round(255 * float(opacity))), 0).astype(np.uint8)
    log_rgba_grid(rec, entity, rgba, geometry, z=z, static=static)
    if map_entity is not None:
        s.log(map_entity, room_annotation_context(ids, names), static=True, strict=True)
        s.log(map_entity, rr.SegmentationImage(lab16, opacity=opacity, draw_order=0.0), static=static,
              strict=True)


def world_to_map2d(geometry: GridGeometry, xy: ArrayLike) -> NDArray[np.float64]:
    """World (x, y) (N, 2) -> positions in the 2D map view (x = column, y = row, pixel corners at integers)."""
    rc = geometry.world_to_pixel(np.asarray(xy, dtype=float)[..., :2])
    return np.stack([rc[..., 1] + 0.5, rc[..., 0] + 0.5], -1)


def log_map2d_path(
    rec: Any, name: str, poses: Any, geometry: GridGeometry, *, color: ArrayLike | None = None,
    radius: float = 1.0, static: bool = True,
) -> None:
    """A path drawn over the 2D map view at ``map/paths/NAME`` (radius in pixels; ``static=False`` logs it at
    the current time, for a path that grows)."""
    xy = _path_positions(poses, None)[:, :2]
    color = VIEWER_SERIES_COLORS.get(name, VIEWER_SERIES_COLORS["other"]) if color is None else color
    _stream(rec).log(f"{MAP2D}/paths/{name}",
                     rr.LineStrips2D([world_to_map2d(geometry, xy)], colors=color, radii=radius,
                                     draw_order=10.0), static=static, strict=True)


def log_map2d_robot(rec: Any, pose: ArrayLike, geometry: GridGeometry, *, entity: str = f"{MAP2D}/robot",
                    length: float = 0.6, color: ArrayLike = ROBOT_COLOR) -> None:
    """The robot in the 2D map view at the current time: a dot and an arrow ``length`` metres along its heading."""
    p = _pose6(pose)
    x, y, yaw = p[0], p[1], p[5]
    a, b = world_to_map2d(geometry, np.array([[x, y], [x + length * np.cos(yaw), y + length * np.sin(yaw)]]))
    s = _stream(rec)
    s.log(entity, rr.Arrows2D(origins=[a], vectors=[b - a], colors=color, radii=1.5, draw_order=40.0),
          rr.Points2D([a], colors=color, radii=4.0, draw_order=40.0), strict=True)


def log_map2d_robots(rec: Any, poses: ArrayLike, geometry: GridGeometry, indexes: ArrayLike, stamps: ArrayLike, *,
                     entity: str = f"{MAP2D}/robot", length: float = 0.6, color: ArrayLike = ROBOT_COLOR) -> None:
    """:func:`log_map2d_robot` at many times in one call (columns): the robot at ``poses[i]`` at frame
    ``indexes[i]`` (the ``scan`` timeline) and ``stamps[i]`` seconds (``time``)."""
    p = _pose6(poses)
    if p.ndim != 2:
        raise ShapeError(f"poses must be (K, 3) or (K, 6), got shape {np.shape(poses)}")
    idx = np.asarray(indexes, dtype=np.int64)
    st = np.asarray(stamps, dtype=float)
    if not (len(idx) == len(st) == len(p)):
        raise ShapeError(f"{len(p)} poses, {len(idx)} indexes and {len(st)} stamps: expected as many of each")
    if len(p) == 0:
        return
    x, y, yaw = p[:, 0], p[:, 1], p[:, 5]
    a = world_to_map2d(geometry, np.column_stack([x, y]))
    b = world_to_map2d(geometry, np.column_stack([x + length * np.cos(yaw), y + length * np.sin(yaw)]))
    unix = st > _UNIX_TIME_THRESHOLD
    for part in (np.flatnonzero(unix), np.flatnonzero(~unix)):
        if not len(part):
            continue
        when = (rr.TimeColumn("time", timestamp=st[part]) if unix[part[0]]
                else rr.TimeColumn("time", duration=st[part]))
        k = len(part)
        cols = [*rr.Arrows2D.columns(origins=a[part], vectors=(b - a)[part],
                                     colors=np.tile(np.asarray(color, dtype=np.uint8), (k, 1)),
                                     radii=np.full(k, 1.5, dtype=np.float32), draw_order=np.full(k, 40.0)),
                *rr.Points2D.columns(positions=a[part], colors=np.tile(np.asarray(color, dtype=np.uint8), (k, 1)),
                                     radii=np.full(k, 4.0, dtype=np.float32), draw_order=np.full(k, 40.0))]
        _stream(rec).send_columns(entity, indexes=[rr.TimeColumn("scan", sequence=idx[part]), when], columns=cols,
                                  strict=True)


def log_map2d_points(rec: Any, name: str, points_world: ArrayLike, geometry: GridGeometry, *,
                     color: ArrayLike = (230, 90, 30), radius: float = 1.2, static: bool = False) -> None:
    """World points (N, 2+) in the 2D map view at ``map/NAME`` (radius in pixels), at the current time."""
    p = _points(points_world, (2, 3), "points_world")
    _stream(rec).log(f"{MAP2D}/{name}", rr.Points2D(world_to_map2d(geometry, p[:, :2]), colors=color, radii=radius,
                                                  draw_order=35.0), static=static, strict=True)


def log_rgba_grid(
    rec: Any, entity: str, image: ArrayLike, geometry: GridGeometry, *, z: float = 0.0, static: bool = True,
) -> None:
    """An (H, W, 3) or (H, W, 4) uint8 picture over a grid, in the 3D world, placed by ``geometry``: a textured
    quad (``Mesh3D``). Rows as an image's and a ``GridMap``'s: row 0 on the side of largest y, so it lies on
    the occupancy grid. (rerun 0.41 flags a colour ``GridMap`` as an error in the view, so colour pictures go this way.)"""
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] not in (3, 4) or img.dtype != np.uint8:
        raise ShapeError(f"{entity}: a picture must be (H, W, 3|4) uint8, got {img.shape} {img.dtype}")
    _check_geometry(geometry, img.shape, entity)
    h, w = img.shape[:2]
    x0, y0 = float(geometry.origin[0]), float(geometry.origin[1])
    x1, y1 = x0 + w * geometry.resolution, y0 + h * geometry.resolution
    # nearest-neighbour look: a texture is filtered linearly, so each cell is drawn as a 4 x 4 block
    big = np.ascontiguousarray(np.repeat(np.repeat(img, 4, axis=0), 4, axis=1)) if max(h, w) <= 1024 else img
    _stream(rec).log(entity, rr.Mesh3D(
        vertex_positions=[[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]],
        triangle_indices=[[0, 1, 2], [0, 2, 3]],
        vertex_texcoords=[[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]],  # row 0 (v = 0) on the far side
        albedo_texture=big,
    ), static=static, strict=True)


# --- room graph ----------------------------------------------------------------------------------------


def _node_kind(data: Mapping[str, Any]) -> str:
    kind = data.get("kind", data.get("type"))
    if kind is not None:
        return str(kind)
    return "room" if "area" in data else "door"


def _centroid(node: Any, data: Mapping[str, Any]) -> NDArray[np.float64]:
    c = data.get("centroid")
    if c is None:
        raise InputError(f"graph node {node!r} has no 'centroid' (x, y) attribute")
    c = np.asarray(c, dtype=float).reshape(-1)
    if c.shape[0] < 2 or not np.all(np.isfinite(c[:2])):
        raise InputError(f"graph node {node!r}: centroid must be finite (x, y), got {data.get('centroid')!r}")
    return c[:2]


@dataclass
class _GraphNodes:
    """A room graph's nodes as drawn: ids, world (x, y), long and short labels, colours, radii, kinds."""

    ids: list[str]
    pos: NDArray[np.float64]
    labels: list[str]
    short: list[str]
    colors: list
    radii: NDArray[np.float64]
    kinds: list[str]


@dataclass
class _GraphEdges:
    """A room graph's edges: node id pairs, their world lines and their length labels."""

    pairs: list[tuple[str, str]]
    lines: list[list[NDArray[np.float64]]]
    labels: list[str]


def _graph_nodes(graph: Any) -> _GraphNodes:
    ids, pos, labels, short, colors, radii, kinds = [], [], [], [], [], [], []
    for i, (n, data) in enumerate(graph.nodes(data=True)):
        kind = _node_kind(data)
        c = _centroid(n, data)
        ids.append(str(n))
        pos.append(c)
        kinds.append(kind)
        if kind == "room":
            area = data.get("area")
            name = data.get("name") or f"room {n}"
            labels.append(f"{name} ({float(area):.1f} m²)" if area is not None else str(name))
            short.append(str(name))
            lab = data.get("label", n if isinstance(n, (int, np.integer)) else i + 1)
            colors.append(label_color(int(lab)) if isinstance(lab, (int, np.integer)) else tuple(ROOM_PALETTE[0]))
            radii.append(1.0)
        else:
            name = str(data.get("name") or f"door {n}")
            labels.append(name)
            short.append(name)
            colors.append(_DOOR_COLOR)
            radii.append(0.5)
    if not ids:
        raise InputError("the room graph has no nodes")
    return _GraphNodes(ids, np.array(pos), labels, short, colors, np.array(radii), kinds)


def _graph_edges(graph: Any, pos: NDArray[np.float64], index: Mapping[str, int]) -> _GraphEdges:
    edges, edge_lines, edge_labels = [], [], []
    for u, v, data in graph.edges(data=True):
        edges.append((str(u), str(v)))
        edge_lines.append([pos[index[str(u)]], pos[index[str(v)]]])
        d = data.get("distance")
        edge_labels.append(f"{float(d):.2f} m" if d is not None else "")
    return _GraphEdges(edges, edge_lines, edge_labels)


def _log_world_graph(s: Any, world_entity: str, nodes: _GraphNodes, edges: _GraphEdges, z: float,
                     static: bool) -> None:
    """The graph in the 3D world at height ``z``: nodes, room labels, light edges and each edge's length."""
    p3 = np.column_stack([nodes.pos, np.full(len(nodes.pos), z)])
    # labels in white: a room's label in its own colour would vanish on its floor's fill
    s.log(f"{world_entity}/nodes", rr.Points3D(p3, colors=nodes.colors, radii=nodes.radii * 0.2),
          static=static, strict=True)
    # rooms only: door labels would crowd a corridor's (the door clouds and the edges show the doors)
    rooms = np.array([k == "room" for k in nodes.kinds])
    s.log(f"{world_entity}/labels", rr.Points3D(p3[rooms] + [0.0, 0.0, 0.25], colors=(255, 255, 255),
                                                radii=0.01, labels=[t for t, r in zip(nodes.labels, rooms, strict=True)
                                                                    if r], show_labels=True),
          static=static, strict=True)
    if edges.pairs:
        lines = [np.column_stack([np.array(e), np.full(2, z)]) for e in edges.lines]
        s.log(f"{world_entity}/edges", rr.LineStrips3D(lines, colors=(235, 235, 235), radii=0.06),
              static=static, strict=True)
        mids = np.array([ln.mean(axis=0) for ln in lines])
        s.log(f"{world_entity}/lengths", rr.Points3D(mids, colors=(235, 235, 235), radii=0.08,
                                                     labels=edges.labels, show_labels=True),
              static=static, strict=True)


def _log_map_graph(s: Any, geometry: GridGeometry, nodes: _GraphNodes, edges: _GraphEdges, static: bool) -> None:
    """The graph over the 2D map view: labels in white (the room's colour is the fill under them), doors by their
    short name."""
    tags = [lab if nodes.kinds[k] == "room" else lab.removeprefix("door ") for k, lab in enumerate(nodes.short)]
    s.log(f"{MAP2D}/graph/nodes", rr.Points2D(world_to_map2d(geometry, nodes.pos), colors=(255, 255, 255),
                                             radii=nodes.radii * 4.0, labels=tags, draw_order=30.0),
          static=static, strict=True)
    if edges.pairs:
        s.log(f"{MAP2D}/graph/edges",
              rr.LineStrips2D([world_to_map2d(geometry, np.array(e)) for e in edges.lines],
                              colors=(40, 40, 40), radii=1.0, draw_order=25.0), static=static, strict=True)


def log_room_graph(
    rec: Any,
    graph: Any,
    *,
    entity: str = GRAPH,
    world_entity: str | None = f"{WORLD_MAP}/graph",
    geometry: GridGeometry | None = None,
    z: float = 0.3,
    scale: float = 40.0,
    static: bool = True,
) -> None:
    """Log a room/door graph (networkx): rooms have ``centroid`` (x, y) and ``area`` (m^2), doors a
    ``centroid``; edges may carry ``distance`` (m). A node's ``kind`` ("room"/"door") wins over the guess
    from ``area``; a room's ``label`` attribute (its id in the label image) picks its colour.

    Logs ``GraphNodes``/``GraphEdges`` at ``entity`` (positions world (x, -y) * ``scale``, so the graph view
    looks like the map from above; a door lying on the line between its two rooms is drawn a little aside,
    so that its label does not cover theirs), the same graph in the 3D world at height ``z`` (``world_entity``:
    light edges and each edge's length at its middle), and, with ``geometry``, over the 2D map view
    (``map/graph``: labels in white, not in the room's own colour, which is the fill under them; doors by
    their short name).
    """
    if not hasattr(graph, "nodes") or not hasattr(graph, "edges"):
        raise InputError(f"expected a networkx graph, got {type(graph).__name__}")
    nodes = _graph_nodes(graph)
    index = {str(n): k for k, n in enumerate(graph.nodes)}
    edges = _graph_edges(graph, nodes.pos, index)
    s = _stream(rec)
    gpos = _graph_positions(graph, nodes.pos, nodes.kinds, index) * np.array([1.0, -1.0]) * scale
    s.log(entity, rr.GraphNodes(nodes.ids, positions=gpos, labels=nodes.labels, colors=nodes.colors,
                                radii=nodes.radii * 0.15 * scale, show_labels=True),
          static=static, strict=True)
    s.log(entity, rr.GraphEdges(edges.pairs, graph_type="undirected"), static=static, strict=True)
    if world_entity is not None:
        _log_world_graph(s, world_entity, nodes, edges, z, static)
    if geometry is not None:
        _log_map_graph(s, geometry, nodes, edges, static)


_DOOR_COLOR = (230, 230, 230)


def _graph_positions(graph: Any, pos: NDArray[np.float64], kinds: list[str], index: Mapping[str, int]
                     ) -> NDArray[np.float64]:
    """Node positions for the graph view: the map's, except that a door lying (nearly) on the line between
    its two rooms moves aside, perpendicular to that line, by a third of the rooms' distance (else the door's
    label and the rooms' overlap when rooms follow each other along a corridor)."""
    out = pos.copy()
    for n in graph.nodes:
        k = index[str(n)]
        if kinds[k] != "door":
            continue
        rooms = [index[str(m)] for m in graph.neighbors(n) if kinds[index[str(m)]] == "room"]
        if len(rooms) != 2:
            continue
        a, b = pos[rooms[0]], pos[rooms[1]]
        ab = b - a
        length = float(np.hypot(*ab))
        if length < 1e-9:
            continue
        normal = np.array([-ab[1], ab[0]]) / length
        off = float(np.dot(pos[k] - a, normal))
        if abs(off) < 0.15 * length:
            out[k] = pos[k] + normal * (np.sign(off) if off else 1.0) * (length / 3.0 - abs(off))
    return out
