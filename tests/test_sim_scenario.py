"""Scenario files: the shipped worlds, their ground truth, and every malformed file named by file, key, problem."""

import copy
import subprocess
import sys

import numpy as np
import pytest
import yaml
from scipy import ndimage

from hsmap.errors import HsmapError, ScenarioError
from hsmap.sim import list_scenarios, load_scenario, parse_scenario
from hsmap.sim.catalog import resolve_scenario
from hsmap.sim.layout import door_records, rasterize_rooms

VALID = {
    "name": "tiny",
    "wall_thickness": 0.2,
    "walls": [
        {"name": "south", "from": [0, 0], "to": [8, 0]},
        {"name": "east", "from": [8, 0], "to": [8, 4]},
        {"name": "north", "from": [8, 4], "to": [0, 4]},
        {"name": "west", "from": [0, 4], "to": [0, 0]},
        {"name": "middle", "from": [4, 0], "to": [4, 4], "thickness": 0.15},
    ],
    "doors": [{"name": "d", "wall": "middle", "at": 2.0, "width": 0.9}],
    "rooms": [{"name": "left", "rect": [0, 0, 4, 4]}, {"name": "right", "rect": [4, 0, 8, 4]}],
    "furniture": [{"type": "table", "center": [2.0, 3.0]}, {"type": "shelf", "center": [6.0, 3.6]}],
    "route": {"start": [1.0, 1.0, 0], "steps": [[3.0, 1.0], [3.0, 2.0], [6.0, 2.0], {"turn": 90}]},
}


def write(tmp_path, data, name="scn.yaml"):
    p = tmp_path / name
    p.write_text(yaml.safe_dump(data), encoding="utf-8")
    return p


def test_valid_tiny_scenario_parses(tmp_path):
    scn = load_scenario(write(tmp_path, VALID))
    assert [w.name for w in scn.walls] == ["south", "east", "north", "west", "middle"]
    assert scn.doors[0].wall == 4 and scn.doors[0].at == 2.0
    assert len(scn.sha256) == 64


@pytest.mark.parametrize(
    "mutate, key, problem",
    [
        (lambda d: d.update(colour="red"), "", "unknown key(s) ['colour']"),
        (lambda d: d["walls"][1].update(thikness=0.2), "walls[1]", "unknown key(s) ['thikness']"),
        (lambda d: d["furniture"][0].update(heigth=1), "furniture[0]", "unknown key(s) ['heigth']"),
        (lambda d: d["route"]["steps"].append({"goto": [1, 1], "backwards": True}), "route.steps[4]",
         "unknown key(s) ['backwards']"),
        (lambda d: d.update(robot={"max_sped": 1}), "robot", "unknown key(s) ['max_sped']"),
        (lambda d: d.update(sensors={"lidar2d": {"fov": 180}}), "sensors.lidar2d", "unknown key(s) ['fov']"),
        # overlapping walls
        (lambda d: d["walls"].append({"from": [2, 0.05], "to": [6, 0.05]}), "walls[5]", "overlaps walls[0]"),
        (lambda d: d["walls"].append({"from": [8, 3], "to": [8, 1]}), "walls[5]", "overlaps walls[1]"),
        # door wider than its wall, and other door problems
        (lambda d: d["walls"].append({"name": "stub", "from": [6, 4], "to": [6, 3.4]})
         or d["doors"].append({"wall": "stub", "at": 0.3, "width": 0.9}), "doors[1].width",
         "wider than its wall walls[5] 'stub'"),
        (lambda d: d["doors"][0].update(at=3.8), "doors[0]", "runs past the end of the wall"),
        (lambda d: d["doors"][0].update(height=3.5), "doors[0].height", "taller than"),
        (lambda d: d["doors"].append({"wall": "middle", "at": 2.5}), "doors[1]", "overlaps doors[0]"),
        (lambda d: d["doors"].append({"center": [9, 9]}), "doors[1].center", "is not on any wall"),
        (lambda d: d["doors"][0].update(wall="nope"), "doors[0].wall", "no wall named 'nope'"),
        (lambda d: d["doors"].append({"wall": "west", "at": 0.3}), "doors[1]", "runs past the end"),
        (lambda d: d["doors"].append({"wall": "south", "at": 4.3}), "doors[1]", "blocked by walls[4]"),
        # a route through a wall (a closed door, furniture)
        (lambda d: d["route"]["steps"].insert(0, [5.0, 1.0]), "route.steps[0]", "passes through walls[4] 'middle'"),
        (lambda d: d["doors"][0].update(open=False), "route.steps[2]", "passes through doors[0] 'd' (closed)"),
        (lambda d: d["route"]["steps"].insert(2, [3.0, 3.0]), "route.steps[2]", "furniture[0] (table)"),
        (lambda d: d["route"].update(start=[0.15, 1.0]), "route.start", "starts"),
        (lambda d: d["route"]["steps"].append([6.0, 3.2]), "route.steps[4]", "closer than the robot radius"),
        # other malformed values
        (lambda d: d["walls"][0].update(thickness=-1), "walls[0].thickness", "must be > 0"),
        (lambda d: d["walls"][0].update(to=[0, 0]), "walls[0]", "zero length"),
        (lambda d: d["furniture"].append({"type": "piano", "center": [1, 1]}), "furniture[2].type",
         "unknown furniture type 'piano'"),
        (lambda d: d["furniture"].append({"type": "cabinet", "center": [4.0, 1.0]}), "furniture[2]",
         "stands inside walls[4]"),
        (lambda d: d["rooms"].append({"name": "overlap", "rect": [3, 1, 5, 3]}), "rooms[2]", "overlaps room"),
        (lambda d: d["rooms"][1].update(name="left"), "rooms[1].name", "duplicate room name"),
        (lambda d: d["route"]["steps"].append({"turn": "left"}), "route.steps[4].turn", "expected a finite number"),
        (lambda d: d.pop("route"), "", "missing required key(s) ['route']"),
        (lambda d: d.update(sensors={"lidar3d": {"channels": 0}}), "sensors.lidar3d", "channels"),
        (lambda d: d.update(sensors={"lidar3d": {"position": [0, 0, 3.0]}}), "sensors.lidar3d.position",
         "not below the ceiling"),
        (lambda d: d.update(sensors={"lidar2d": {"scan_time": -0.1}}), "sensors.lidar2d", "scan_time must be in"),
        (lambda d: d.update(frame_rate=20.0, sensors={"lidar2d": {"scan_time": 0.1}}), "sensors.lidar2d.scan_time",
         "outlasts the frame period"),
    ],
)
def test_bad_scenarios_name_file_key_and_problem(tmp_path, mutate, key, problem):
    data = copy.deepcopy(VALID)
    mutate(data)
    path = write(tmp_path, data, "bad-scenario.yaml")
    with pytest.raises(ScenarioError) as exc:
        load_scenario(path)
    msg = str(exc.value)
    assert msg.startswith(str(path) + ": "), msg
    assert key in msg and problem in msg, msg
    assert isinstance(exc.value, HsmapError)


def test_unreadable_scenario_files(tmp_path):
    with pytest.raises(ScenarioError, match="no such scenario file"):
        load_scenario(tmp_path / "missing.yaml")
    p = tmp_path / "broken.yaml"
    p.write_text("name: [unclosed\n", encoding="utf-8")
    with pytest.raises(ScenarioError, match="broken.yaml: not valid YAML"):
        load_scenario(p)
    with pytest.raises(ScenarioError, match="unknown scenario 'no-such-world'"):
        resolve_scenario("no-such-world")


def test_cli_reports_a_bad_scenario_in_one_line(tmp_path):
    data = copy.deepcopy(VALID)
    data["route"]["steps"].insert(0, [5.0, 1.0])
    path = write(tmp_path, data, "through-wall.yaml")
    r = subprocess.run([sys.executable, "-m", "hsmap.cli", "simulate", str(path), "--out", str(tmp_path / "o")],
                       capture_output=True, text=True)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("hsmap: error: ") and "through-wall.yaml" in lines[0]
    assert "route.steps[0]" in lines[0] and "passes through walls[4]" in lines[0]
    assert not (tmp_path / "o").exists()


def test_shipped_scenarios_load():
    assert {"slam-office", "two-rooms"} <= set(list_scenarios())
    for name in list_scenarios():
        scn = load_scenario(resolve_scenario(name))
        assert scn.name == name and scn.rooms and scn.doors and len(scn.furniture) >= 10
        # furniture at realistic heights: low pieces the 2D LiDAR sees and the 3D LiDAR's ring passes over
        heights = [f.height for f in scn.furniture]
        assert min(heights) < 1.0 and any(1.5 <= h <= 2.0 for h in heights)
        assert all(0.8 <= d.width <= 0.9 for d in scn.doors)
        assert 2.6 <= scn.wall_height <= 3.0 and scn.ceiling_height == scn.wall_height


def test_two_rooms_ground_truth_labels_and_doors():
    scn = load_scenario(resolve_scenario("two-rooms"))
    labels, grid, names, _ = rasterize_rooms(scn, 0.05)
    assert labels.dtype == np.uint16
    assert names == {1: "room-a", 2: "corridor", 3: "room-b"}
    assert set(np.unique(labels)) == {0, 1, 2, 3}

    def at(x, y):
        r, c = grid.world_to_index([x, y])
        return int(labels[r, c])

    assert at(3.0, 2.5) == 1 and at(7.25, 2.5) == 2 and at(11.5, 2.5) == 3  # furniture does not matter
    assert at(6.0, 2.5) == 0 and at(8.5, 2.5) == 0  # doorways are cut
    assert at(3.0, 0.05) == 0 and at(-0.3, 2.0) == 0 and at(7.25, 1.0) == 0  # wall, outside, between
    # areas: inside the wall faces
    area = {k: np.count_nonzero(labels == k) * grid.resolution**2 for k in names}
    assert area[1] == pytest.approx((6 - 0.2) * (5 - 0.2), rel=0.02)
    assert area[2] == pytest.approx((2.5 - 0.2) * (1.6 - 0.15), rel=0.04)
    assert area[3] == pytest.approx(area[1], rel=0.01)
    # each room is one piece and no two rooms touch (4-connectivity)
    for k in names:
        assert ndimage.label(labels == k)[1] == 1
    for shift in ((0, 1), (1, 0)):
        a = labels[: labels.shape[0] - shift[0], : labels.shape[1] - shift[1]]
        b = labels[shift[0]:, shift[1]:]
        assert not np.any((a > 0) & (b > 0) & (a != b))
    # the same rooms at another resolution
    coarse, g2, _, _ = rasterize_rooms(scn, 0.1)
    assert coarse.shape[0] == pytest.approx(labels.shape[0] / 2, abs=1)
    r, c = g2.world_to_index([11.5, 2.5])
    assert coarse[r, c] == 3
    doors = door_records(scn)
    assert [d["name"] for d in doors] == ["door-a", "door-b"]
    assert doors[0]["center"] == pytest.approx([6.0, 2.5]) and doors[1]["center"] == pytest.approx([8.5, 2.5])
    assert all(d["width"] == 0.9 and d["open"] for d in doors)
    assert set(doors[0]["rooms"]) == {"room-a", "corridor"} and set(doors[1]["rooms"]) == {"corridor", "room-b"}
    assert np.hypot(*np.subtract(*doors[0]["endpoints"])) == pytest.approx(0.9)


def test_slam_office_ground_truth():
    scn = load_scenario(resolve_scenario("slam-office"))
    labels, grid, names, _ = rasterize_rooms(scn)
    assert len(names) == 8 and set(np.unique(labels)) == set(range(9))
    doors = door_records(scn)
    assert len(doors) == 11
    corridor_doors = [d for d in doors if "corridor" in d["rooms"]]
    assert len(corridor_doors) == 8  # the look-alike doors
    closed = [d for d in doors if not d["open"]]
    assert len(closed) == 1 and set(closed[0]["rooms"]) == {"office-1", "office-2"}
    # the corridor is about 15 m long
    ys, xs = np.nonzero(labels == [k for k, v in names.items() if v == "corridor"][0])
    assert (xs.max() - xs.min() + 1) * grid.resolution == pytest.approx(15 - 0.25 / 2 - 0.2 / 2, abs=0.1)


def test_parse_without_file_names_the_placeholder():
    with pytest.raises(ScenarioError, match=r"^<scenario>: walls: a scenario needs at least one wall"):
        parse_scenario({"name": "x", "walls": [], "route": {"start": [0, 0], "steps": [[1, 0]]}})
