"""Segment a 2D map into rooms: doors (skeleton x distance transform), room labels and the room/door graph.

MAP is a PNG/PGM image (pixels >= 250 are free, the benchmark's rule; 0.05 m per pixel unless --resolution)
or a ROS map_server YAML (its image, resolution, origin and thresholds), or a 3D map (OctoMap .bt/.ot, or a
.ply/.pcd point map) with --band LO,HI: the band's occupancy grid in heights above the floor (the floor found as
the lowest large horizontal layer of occupied voxels, or --floor Z) is written as grid.yaml + grid.pgm
(map_server trinary: occupied, observed free, unknown) and band.json (floor, band, cell counts), and segmented as
an image would be. MAP may also be a run's output folder (``hsmap map`` or ``hsmap slam``): its 3D map (map3d.bt
with its free space, else map3d.ply or map.ply with free space carved from the sensor's positions along the
trajectory) cut at --band above the floor found under the path (the floor under the nearest sensor pose: several
floor levels). The free space segmented is the band's observed free cells and its unknown cells whose column
the sensor saw through (observed free at another height, nothing occupied within 0.3 m of the band: no wall there;
``hsmap.maps.maps3d.seen_through``), so that a room seen through its door from a corridor is one space and not a fan
of rays, less passages narrower than the narrowest door (2 x min_door_half_width: cracks in walls the sensor
partly missed); its occupied cells stay walls. Writes into --out: rooms.png (16-bit room labels, 0 = no room, same
size as the map), doors.json, topology.json, topology.graphml, topology.txt (readable listing), segmentation.png
(coloured overlay, doors magenta, with a key) and segmentation_config.yaml (the effective configuration); --steps adds steps.png, a panel
per step of the algorithm.
"""

from __future__ import annotations

import argparse

NAME = "segment"
HELP = "detect doors and segment a 2D map into rooms, with the room/door graph"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("map", help="map image (PNG/PGM; >= 250 free), map_server YAML, or a 3D map (.bt, .ot, "
                                    ".ply, .pcd) or a run's output folder (hsmap map, hsmap slam) with --band")
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--resolution", type=float, default=None,
                        help="metres per pixel (default: the YAML's, or 0.05 for images)")
    parser.add_argument("--config", default=None, help="YAML file with SegmentationConfig fields")
    parser.add_argument("--method", choices=("critical", "paper"), default=None,
                        help="door detection: critical points + narrowing test (default) or the paper's band")
    parser.add_argument("--furniture", action="store_true",
                        help="give occupied pixels enclosed by a room (furniture) that room's label")
    parser.add_argument("--steps", action="store_true", help="also write steps.png (a panel per step)")
    parser.add_argument("--band", metavar="LO,HI", default=None,
                        help="3D maps: the height band in metres above the floor (e.g. 1.7,1.8)")
    parser.add_argument("--floor", type=float, default=None, metavar="Z",
                        help="3D maps: the floor's height in the map's frame (default: found in the map)")


#: The files ``hsmap segment`` writes into --out.
OUTPUTS = ("rooms.png", "doors.json", "topology.json", "topology.graphml", "topology.txt", "segmentation.png",
           "segmentation_config.yaml", "steps.png", "grid.yaml", "grid.pgm", "band.json")

#: Endings of the 3D maps ``hsmap segment`` reads with --band.
MAP3D_SUFFIXES = (".bt", ".ot", ".ply", ".pcd")


#: A run's output folder: its 3D map and the trajectory of the sensor's base, in the order they are looked for.
RUN_MAPS = (("map3d.bt", "trajectory3d.tum"), ("map3d.ply", "trajectory3d.tum"), ("map.ply", "trajectory.tum"))


def _extrinsic3d(folder):
    """The 3D LiDAR's offset in the base frame that a run's metrics.json records (zero when it has none)."""
    import json

    import numpy as np

    try:
        info = json.loads((folder / "metrics.json").read_text(encoding="utf-8")).get("input_info") or {}
    except (OSError, ValueError, AttributeError):
        info = {}
    for part in (info.get("clouds") or {}, info):
        value = ((part.get("extrinsics") or {}).get("3d") or {}).get("value") if isinstance(part, dict) else None
        if value is not None and len(value) == 6:
            return np.asarray(value, dtype=float)
    return np.zeros(6)


def _run_folder_map(folder, resolution: float | None):
    """A run's folder (``hsmap map`` or ``hsmap slam``): its 3D map with free space (an OctoMap's own, or carved
    from the sensor's positions along the trajectory) and the sensor's world positions."""
    from pathlib import Path

    from ..errors import DatasetError, InputError
    from ..geometry import pose_to_matrix
    from ..maps.maps3d import read_map3d
    from ..trajectory import read_tum

    folder = Path(folder)
    for map_name, traj_name in RUN_MAPS:
        if (folder / map_name).is_file() and (folder / traj_name).is_file():
            break
    else:
        raise DatasetError(f"{folder}: a folder, not a 3D map file nor a run's output folder (expected a .bt, .ot, "
                           ".ply or .pcd file, or a folder with map3d.bt or map3d.ply and trajectory3d.tum, from "
                           "hsmap map, or map.ply and trajectory.tum, from hsmap slam)")
    T = pose_to_matrix(read_tum(folder / traj_name).as_6dof().poses) @ pose_to_matrix(_extrinsic3d(folder))
    positions = T[:, :3, 3]
    if map_name.endswith(".bt"):
        if resolution is not None:
            raise InputError(f"--resolution applies to point maps; {folder / map_name} has its own resolution")
        return read_map3d(folder / map_name), positions, map_name
    kw = {} if resolution is None else {"resolution": float(resolution)}
    return read_map3d(folder / map_name, poses=positions, **kw), positions, map_name


def _map_and_floor(args):
    """The 3D map to cut, the floor to cut it at (a height, or 0 in a map levelled to the floor under the path),
    and band.json's facts about them."""
    from pathlib import Path

    import numpy as np

    from ..errors import EmptyInputError, InputError
    from ..maps.maps3d import FREE as FREE_3D
    from ..maps.maps3d import floor_height, read_map3d
    from ..maps.occupancy3d import floor_field, floor_under_path, level_map
    from ..pipeline.config import GridsConfig

    if not Path(args.map).is_dir():
        kw = {} if args.resolution is None else {"resolution": float(args.resolution)}
        if kw and not args.map.lower().endswith((".ply", ".pcd")):
            raise InputError(f"--resolution applies to point maps (.ply/.pcd); {args.map} has its own resolution")
        m = read_map3d(args.map, **kw)
        if not (m.state == FREE_3D).any():
            what = ("a point map records occupied voxels only, no free space"
                    if args.map.lower().endswith((".ply", ".pcd")) else "the map holds no free voxel")
            raise EmptyInputError(f"{args.map}: {what}, so its band has no free cell to segment; segment an OctoMap "
                                  ".bt/.ot that records free space, or the output folder of the hsmap map or hsmap "
                                  "slam run that made it (its free space is carved along the rays)")
        found = floor_height(m)
        floor = found if args.floor is None else float(args.floor)
        return m, floor, {"floor": floor, "floor_found": found, "floor_source":
                          "found (lowest large horizontal layer of occupied voxels)" if args.floor is None
                          else "--floor"}
    m, positions, name = _run_folder_map(args.map, args.resolution)
    if args.floor is not None:
        return m, float(args.floor), {"map3d": name, "floor": float(args.floor), "floor_source": "--floor"}
    g = GridsConfig()
    floors = floor_under_path(m, positions, radius=g.floor_radius, depth=g.floor_depth)
    info = {"map3d": name, "floor": float(np.median(floors)), "floor_found": [float(floors.min()), float(floors.max())],
            "floor_source": f"under the path ({len(floors)} sensor poses; the band follows the floor under the "
                            f"nearest pose, or the column's own within {g.floor_reach:g} m of it)"}
    return level_map(m, floor_field(m, positions, floors, reach=g.floor_reach)), 0.0, info


def _band_grid(args: argparse.Namespace, min_passage: float):
    """A 3D map's band: its occupancy grid, the grid segmented (seen-through cells free), band.json's facts."""
    import math

    import numpy as np

    from ..errors import InputError
    from ..maps.grid import FREE, OCCUPIED, UNKNOWN, OccupancyGrid
    from ..maps.maps3d import band_grid, band_layers, seen_through, segmentation_free
    from .inputs import parse_vector

    if args.band is None:
        raise InputError(f"{args.map}: a 3D map needs --band LO,HI (metres above the floor, e.g. 1.7,1.8)")
    lo, hi = parse_vector(args.band, 2, "--band")
    if not lo < hi:
        raise InputError(f"--band must be LO,HI with LO < HI, got {args.band!r}")
    if args.floor is not None and not math.isfinite(args.floor):
        raise InputError(f"--floor must be a finite height in metres, got {args.floor}")
    m, floor, floor_info = _map_and_floor(args)
    layers = band_layers(m, lo, hi, floor=floor)
    grid = band_grid(m, lo, hi, floor=floor)
    seen = seen_through(m, lo, hi, floor=floor)
    z = m.origin[2] + np.arange(layers.start, layers.stop + 1) * m.resolution
    info = {
        "map": str(args.map),
        "resolution": m.resolution,
        "voxels": list(m.shape),
        "origin": m.origin.tolist(),
        **floor_info,
        "band": [float(lo), float(hi)],
        "band_heights": [float(z[0]), float(z[-1])],
        "cells": {"occupied": int(grid.occupied.sum()), "free": int(grid.free.sum()),
                  "unknown": int((~grid.occupied & ~grid.free).sum()),
                  "unknown_seen_through": int(seen.sum())},
    }
    free = segmentation_free(m, lo, hi, floor=floor, min_passage=min_passage)
    info["cells"]["segmented_free"] = int(free.sum())
    data = np.where(free, FREE, np.where(grid.occupied, OCCUPIED, UNKNOWN)).astype(np.int8)
    return grid, OccupancyGrid(data, grid.geometry), info


def run(args: argparse.Namespace) -> int:
    import dataclasses
    import warnings
    from pathlib import Path

    from PIL import Image

    from ..config import dump_config, load_config
    from ..errors import EmptyInputError, HsmapWarning, InputError
    from ..io import (
        atomic_path,
        prepare_output_dir,
        refuse_overwriting_input,
        staged_outputs,
        sweep_stale_temporaries,
        write_json,
    )
    from ..maps.grid import read_map, write_label_image, write_map
    from ..rooms.segmentation import SegmentationConfig, check_scale, segment_rooms
    from ..rooms.topology import room_graph, topology_listing, write_topology
    from ..viz.colors import segmentation_picture

    if args.resolution is not None and not (args.resolution > 0 and args.resolution < float("inf")):
        raise InputError(f"--resolution must be a finite number > 0 of metres per pixel, got {args.resolution}")
    cfg = load_config(SegmentationConfig, args.config) if args.config else SegmentationConfig()
    if args.method:
        cfg = dataclasses.replace(cfg, method=args.method)
    if args.furniture:
        cfg = dataclasses.replace(cfg, assign_furniture=True)
    refuse_overwriting_input(args.out, [args.map, args.config], OUTPUTS)
    out = prepare_output_dir(args.out, "--out", create=False)
    band = None
    if Path(args.map).suffix.lower() in MAP3D_SUFFIXES or Path(args.map).is_dir():
        band_map, grid, band = _band_grid(args, 2.0 * cfg.min_door_half_width)
        print(f"floor at z = {band['floor']:.3f} m ({band['floor_source']}); band {band['band'][0]:g}-"
              f"{band['band'][1]:g} m above it: voxel layers z = {band['band_heights'][0]:.3f}-"
              f"{band['band_heights'][1]:.3f} m; {band['cells']['occupied']} occupied, {band['cells']['free']} free, "
              f"{band['cells']['unknown']} unknown ({band['cells']['unknown_seen_through']} seen through); "
              f"{band['cells']['segmented_free']} cells segmented as free space")
    elif args.band is not None or args.floor is not None:
        raise InputError(f"--band and --floor apply to 3D maps ({', '.join(MAP3D_SUFFIXES)}) and run folders, not "
                         f"{args.map}")
    else:
        grid = read_map(args.map, args.resolution)
    try:
        check_scale(grid.free, grid.geometry.resolution, cfg)
    except EmptyInputError as exc:
        hint = ("; a point map holds occupied points only: segment its run's folder (hsmap segment DIR) to carve "
                "the free space along the trajectory") if Path(args.map).suffix.lower() in (".ply", ".pcd") else ""
        raise EmptyInputError(f"{args.map}: {exc}{hint}") from None
    except InputError as exc:
        suffix = Path(args.map).suffix.lower()
        if args.resolution is not None:
            src = "--resolution"
        elif suffix in (".yaml", ".yml"):
            src = f"{args.map}: 'resolution'"
        elif suffix in (".bt", ".ot"):  # an OctoMap tree's voxel size is its own: no flag changes it
            src = f"{args.map}: the tree's voxel size {grid.geometry.resolution:g} m"
        elif suffix in MAP3D_SUFFIXES:
            src = "the point map's default voxel size 0.05 (set it with --resolution)"
        else:
            src = "the default resolution 0.05 (set it with --resolution)"
        raise InputError(f"{src}: {exc}") from None
    seg = segment_rooms(grid, config=cfg, keep_steps=args.steps)
    if seg.n_rooms == 0:
        warnings.warn(f"{args.map}: no room found (free space {int(grid.free.sum())} pixels at "
                      f"{grid.geometry.resolution:g} m/pixel); is the map or its resolution right?", HsmapWarning,
                      stacklevel=2)
    g = room_graph(seg)
    sweep_stale_temporaries(out, OUTPUTS)
    with staged_outputs(out, replaces=OUTPUTS) as stage:
        write_label_image(stage / "rooms.png", seg.labels)
        write_json(stage / "doors.json", {
            "map": str(args.map),
            "frame": "map (world x, y in metres; map_server origin convention)",
            "resolution": grid.geometry.resolution,
            "origin": list(grid.geometry.origin),
            "doors": [d.as_dict() for d in seg.doors],
        })
        write_topology(g, stage)
        with atomic_path(stage / "segmentation.png") as tmp:
            Image.fromarray(segmentation_picture(seg.labels, grid.free, seg.doors, grid.geometry)).save(tmp, format="PNG")
        dump_config(cfg, stage / "segmentation_config.yaml")
        if band is not None:
            write_map(stage / "grid.yaml", band_map)
            write_json(stage / "band.json", {**band, "rooms": seg.n_rooms, "doors": len(seg.doors)})
        if args.steps:
            from ..viz.map_figures import voronoi_steps_figure

            fig = voronoi_steps_figure(grid, seg, title=Path(args.map).name)
            with atomic_path(stage / "steps.png") as tmp:
                fig.savefig(tmp, dpi=110)
    print(topology_listing(g), end="")
    extra = ", grid.yaml, grid.pgm, band.json" if band is not None else ""
    print(f"wrote {out}/rooms.png, doors.json, topology.json, topology.graphml, segmentation.png{extra}")
    return 0
