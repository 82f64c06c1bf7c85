import json
import re
import subprocess
import sys

import networkx as nx
import numpy as np
import pytest
import yaml
from _worlds import two_rooms
from PIL import Image

from hsmap.maps.grid import read_label_image, write_map
from hsmap.rooms.segmentation import segment_rooms
from hsmap.rooms.topology import (
    graph_to_json,
    read_topology_json,
    room_graph,
    topology_line,
    topology_listing,
    write_topology,
)


@pytest.fixture(scope="module")
def two_rooms_seg():
    return segment_rooms(two_rooms())


def _kinds(g):
    return [g.nodes[n]["kind"] for n in nx.shortest_path(g, *[n for n in g if g.degree(n) == 1])]


def test_two_rooms_graph_is_r_d_r_d_r(two_rooms_seg):
    g = room_graph(two_rooms_seg)
    assert g.number_of_nodes() == 5 and g.number_of_edges() == 4
    assert nx.is_connected(g) and nx.is_tree(g)
    assert sorted(d for _, d in g.degree()) == [1, 1, 2, 2, 2]
    assert _kinds(g) == ["room", "door", "room", "door", "room"]
    # the corridor (middle room) is the one with two doors; its centroid is at (7.25, 2.5)
    mid = next(n for n in g if g.nodes[n]["kind"] == "room" and g.degree(n) == 2)
    assert g.nodes[mid]["x"] == pytest.approx(7.25, abs=0.1) and g.nodes[mid]["y"] == pytest.approx(2.5, abs=0.1)
    for u, v, a in g.edges(data=True):
        door, room = (u, v) if g.nodes[u]["kind"] == "door" else (v, u)
        expect = np.hypot(g.nodes[door]["x"] - g.nodes[room]["x"], g.nodes[door]["y"] - g.nodes[room]["y"])
        assert a["distance"] == pytest.approx(expect)
    # corridor centroid to either door: ~1.25 m; a room centroid (3, 2.5) to its door (6, 2.5): ~3 m
    dists = sorted(a["distance"] for *_, a in g.edges(data=True))
    assert dists[:2] == pytest.approx([1.25, 1.25], abs=0.1) and dists[2:] == pytest.approx([3.0, 3.0], abs=0.1)


def test_listing_and_files(two_rooms_seg, tmp_path):
    g = room_graph(two_rooms_seg)
    text = topology_listing(g)
    assert "3 rooms, 2 doors" in text
    chain = text.strip().splitlines()[-1].strip()
    assert re.fullmatch(r"R\d+ - D\d+ - R\d+ - D\d+ - R\d+", chain), chain
    paths = write_topology(g, tmp_path)
    h = nx.read_graphml(paths["graphml"])
    assert set(h.nodes) == set(g.nodes) and h.number_of_edges() == 4
    assert h.nodes["D1"]["width"] == pytest.approx(g.nodes["D1"]["width"])
    back = read_topology_json(paths["json"])
    assert nx.utils.graphs_equal(back, g)
    assert json.loads(paths["json"].read_text()) == json.loads(json.dumps(graph_to_json(g)))
    assert paths["txt"].read_text() == text


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "hsmap.cli", *map(str, args)], capture_output=True, text=True)


def test_cli_segment_image_and_yaml(tmp_path):
    grid = two_rooms()
    Image.fromarray(np.where(grid.free, 254, np.where(grid.occupied, 0, 205)).astype(np.uint8)).save(tmp_path / "m.png")
    out = tmp_path / "out"
    r = _cli("segment", tmp_path / "m.png", "--out", out)
    assert r.returncode == 0, r.stderr
    assert "R" in r.stdout and " - D" in r.stdout
    for f in ("rooms.png", "doors.json", "topology.json", "topology.graphml", "segmentation.png",
              "segmentation_config.yaml", "topology.txt"):
        assert (out / f).is_file(), f
    labels = read_label_image(out / "rooms.png")
    assert labels.shape == grid.data.shape and labels.max() == 3
    with Image.open(out / "rooms.png") as im:
        assert im.mode.startswith("I")
    doors = json.loads((out / "doors.json").read_text())["doors"]
    assert len(doors) == 2
    # an image has no origin: world (x, y) is relative to its lower-left corner
    ox, oy = grid.geometry.origin
    got = sorted((d["centre"][0] + ox, d["centre"][1] + oy) for d in doors)
    assert np.allclose(got, [(6.0, 2.5), (8.5, 2.5)], atol=0.1)
    cfg = yaml.safe_load((out / "segmentation_config.yaml").read_text())
    assert cfg["door_half_width"] == 0.4 and cfg["min_room_area"] == 1.5
    # the same map as map_server YAML: doors in world coordinates
    from hsmap.cli import main

    yml, _ = write_map(tmp_path / "map.yaml", grid)
    assert main(["segment", str(yml), "--out", str(tmp_path / "out2"), "--steps"]) == 0
    doors = json.loads((tmp_path / "out2" / "doors.json").read_text())["doors"]
    assert np.allclose(sorted(d["centre"] for d in doors), [[6.0, 2.5], [8.5, 2.5]], atol=0.1)
    assert (tmp_path / "out2" / "steps.png").is_file()


def test_cli_segment_bad_input(tmp_path, capsys):
    from hsmap.cli import main

    def fails(*args, match):
        capsys.readouterr()
        assert main(["segment", *map(str, args), "--out", str(tmp_path / "o")]) == 2
        err = capsys.readouterr().err
        assert err.startswith("hsmap: error:") and match in err and len(err.strip().splitlines()) == 1, err

    (tmp_path / "x.png").write_text("not an image at all")
    fails(tmp_path / "x.png", match="x.png")
    Image.fromarray(np.zeros((20, 20), np.uint8)).save(tmp_path / "black.png")
    fails(tmp_path / "black.png", match="no free")
    Image.fromarray(np.full((20, 20), 255, np.uint8)).save(tmp_path / "white.png")
    fails(tmp_path / "white.png", "--resolution", "0", match="resolution")
    fails(tmp_path / "white.png", "--resolution", "-1", match="resolution")
    (tmp_path / "m.yaml").write_text("image: gone.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n")
    fails(tmp_path / "m.yaml", match="gone.pgm")
    fails(tmp_path / "nothere.pgm", match="no such")
    assert not (tmp_path / "o" / "rooms.png").exists()


def test_topology_line_names_every_part_and_door():
    g = nx.Graph()
    for r in ("R1", "R2", "R3", "R4", "R5"):
        g.add_node(r, kind="room")
    for d, rooms in (("D1", ("R1", "R2")), ("D2", ("R2", "R3")), ("D3", ("R3", "R1")), ("D4", ("R4",))):
        g.add_node(d, kind="door")
        g.add_edges_from((d, r) for r in rooms)
    line = topology_line(g)
    # a loop of three rooms is no chain: its doors' links; a door on one room; a room alone
    assert line == "R1 -D1- R2, R2 -D2- R3, R1 -D3- R3; R4 - D4; R5 (no door)", line


def test_topology_line_of_a_chain(two_rooms_seg):
    line = topology_line(room_graph(two_rooms_seg))
    assert re.fullmatch(r"R\d+ - D\d+ - R\d+ - D\d+ - R\d+", line), line
