"""The topological map: a graph with a node per room and per door, as the paper's Figures 12 and 16.

Nodes are named ``R<label>`` (rooms, numbered as in the label image) and ``D<k>`` (doors, 1-based, in the
segmentation's door order). Room nodes carry ``kind="room"``, ``label``, ``x``, ``y`` (centroid, metres) and
``area`` (m^2); door nodes ``kind="door"``, ``x``, ``y`` (centre), ``width`` (metres) and the end points
``x1, y1, x2, y2``. Each door is joined to the two rooms it connects by an edge whose ``distance`` is the
distance between the room's centroid and the door's centre (metres). Only scalar attributes are used, so
the graph round-trips through GraphML.
"""

from __future__ import annotations

import os
from pathlib import Path

import networkx as nx
import numpy as np

from ..io import atomic_path, write_json, write_text

__all__ = ["room_graph", "topology_listing", "topology_line", "write_topology", "graph_to_json", "read_topology_json"]


def room_graph(segmentation) -> nx.Graph:
    """Room/door graph of a :class:`hsmap.rooms.segmentation.Segmentation`.

    Returns
    -------
    networkx.Graph
        Rooms without doors are isolated nodes; doors whose rooms are unknown are left out.
    """
    g = nx.Graph(resolution=float(segmentation.geometry.resolution))
    rooms = {r.label: r for r in segmentation.rooms}
    for lab, r in rooms.items():
        g.add_node(f"R{lab}", kind="room", label=int(lab), x=float(r.centroid[0]), y=float(r.centroid[1]),
                   area=float(r.area))
    for k, d in enumerate(segmentation.doors, start=1):
        ra, rb = (int(v) for v in d.rooms)
        if ra not in rooms or rb not in rooms or ra == rb:
            continue
        name = f"D{k}"
        (x1, y1), (x2, y2) = np.asarray(d.end_points, dtype=float)
        g.add_node(name, kind="door", x=float(d.centre[0]), y=float(d.centre[1]), width=float(d.width),
                   x1=float(x1), y1=float(y1), x2=float(x2), y2=float(y2))
        for lab in (ra, rb):
            dist = float(np.hypot(*(rooms[lab].centroid - np.asarray(d.centre, dtype=float))))
            g.add_edge(f"R{lab}", name, distance=dist)
    return g


def _node_key(name: str) -> tuple[str, int]:
    return name[0], int(name[1:]) if name[1:].isdigit() else 0


def topology_listing(g: nx.Graph) -> str:
    """A readable listing of the graph: rooms, doors, and which door joins which rooms at what distance."""
    rooms = sorted((n for n, a in g.nodes(data=True) if a.get("kind") == "room"), key=_node_key)
    doors = sorted((n for n, a in g.nodes(data=True) if a.get("kind") == "door"), key=_node_key)
    lines = [f"Topological map: {len(rooms)} rooms, {len(doors)} doors"]
    lines.append("Rooms:")
    for n in rooms:
        a = g.nodes[n]
        via = ", ".join(sorted(g.neighbors(n), key=_node_key)) or "-"
        lines.append(f"  {n:>5}  area {a['area']:7.2f} m^2  centroid ({a['x']:7.2f}, {a['y']:7.2f})  doors: {via}")
    lines.append("Doors:")
    for n in doors:
        a = g.nodes[n]
        ends = sorted(g.neighbors(n), key=_node_key)
        link = "  <->  ".join(f"{r} ({g.edges[n, r]['distance']:.2f} m)" for r in ends)
        lines.append(f"  {n:>5}  centre ({a['x']:7.2f}, {a['y']:7.2f})  width {a['width']:.2f} m  {link}")
    comps = [sorted(c, key=_node_key) for c in nx.connected_components(g)]
    lines.append(f"Connected parts: {len(comps)}")
    for c in sorted(comps, key=lambda c: _node_key(c[0])):
        sub = g.subgraph(c)
        ends = [n for n in c if sub.degree(n) <= 1]
        if len(c) > 1 and nx.is_tree(sub) and len(ends) == 2 and max(d for _, d in sub.degree()) <= 2:
            lines.append("  " + " - ".join(nx.shortest_path(sub, *sorted(ends, key=_node_key))))
        else:
            lines.append("  " + ", ".join(c))
    return "\n".join(lines) + "\n"


def topology_line(g: nx.Graph) -> str:
    """The graph in one line: each connected part as its chain of rooms and doors (``R1 - D1 - R2``, a room
    first) where it is one, else as its doors' links (``R1 -D1- R2``) and its rooms without a door
    (``R5 (no door)``); the parts joined by ``"; "``."""
    parts = []
    for c in sorted((sorted(c, key=_node_key) for c in nx.connected_components(g)), key=lambda c: _node_key(c[0])):
        sub = g.subgraph(c)
        ends = [n for n in c if sub.degree(n) <= 1]
        if len(c) > 1 and nx.is_tree(sub) and len(ends) == 2 and max(d for _, d in sub.degree()) <= 2:
            ends = sorted(ends, key=lambda n: (g.nodes[n].get("kind") != "room", _node_key(n)))  # a room first
            parts.append(" - ".join(nx.shortest_path(sub, *ends)))
            continue
        links = []
        for n in c:
            rooms = sorted(sub.neighbors(n), key=_node_key)
            if g.nodes[n].get("kind") == "door":
                links.append((f"{rooms[0]} -{n}- " + " & ".join(rooms[1:])).rstrip() if rooms else f"{n} (no room)")
            elif not rooms:
                links.append(f"{n} (no door)")
        parts.append(", ".join(links))
    return "; ".join(parts)


def graph_to_json(g: nx.Graph) -> dict:
    """JSON-ready dict: ``nodes`` (name + attributes) and ``edges`` (source, target, distance)."""
    return {
        "graph": dict(g.graph),
        "nodes": [{"id": n, **a} for n, a in sorted(g.nodes(data=True), key=lambda t: _node_key(t[0]))],
        "edges": [{"source": u, "target": v, **a} for u, v, a in g.edges(data=True)],
    }


def read_topology_json(path: str | os.PathLike) -> nx.Graph:
    """Read a graph written by :func:`write_topology` (the JSON file)."""
    import json

    data = json.loads(Path(path).read_text(encoding="utf-8"))
    g = nx.Graph(**data.get("graph", {}))
    for n in data["nodes"]:
        n = dict(n)
        g.add_node(n.pop("id"), **n)
    for e in data["edges"]:
        e = dict(e)
        g.add_edge(e.pop("source"), e.pop("target"), **e)
    return g


def write_topology(g: nx.Graph, folder: str | os.PathLike, stem: str = "topology") -> dict[str, Path]:
    """Write ``<stem>.json``, ``<stem>.graphml`` and ``<stem>.txt`` (the listing) into ``folder``, atomically."""

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = {"json": folder / f"{stem}.json", "graphml": folder / f"{stem}.graphml", "txt": folder / f"{stem}.txt"}
    write_json(paths["json"], graph_to_json(g))
    with atomic_path(paths["graphml"]) as tmp:
        nx.write_graphml(g, tmp)
    write_text(paths["txt"], topology_listing(g))
    return paths
