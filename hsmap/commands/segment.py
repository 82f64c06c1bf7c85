"""Segment a 2D map into rooms: doors (skeleton x distance transform), room labels and the room/door graph.

MAP is a PNG/PGM image (pixels >= 250 are free, the benchmark's rule; 0.05 m per pixel unless --resolution)
or a ROS map_server YAML (its image, resolution, origin and thresholds). Writes into --out: rooms.png
(16-bit room labels, 0 = no room, same size as the map), doors.json, topology.json, topology.graphml,
topology.txt (readable listing), segmentation.png (coloured overlay) and segmentation_config.yaml (the
effective configuration); --steps adds steps.png, a panel per step of the algorithm.
"""

from __future__ import annotations

import argparse

NAME = "segment"
HELP = "detect doors and segment a 2D map into rooms, with the room/door graph"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("map", help="map image (PNG/PGM; >= 250 free) or map_server YAML")
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--resolution", type=float, default=None,
                        help="metres per pixel (default: the YAML's, or 0.05 for images)")
    parser.add_argument("--config", default=None, help="YAML file with SegmentationConfig fields")
    parser.add_argument("--method", choices=("critical", "paper"), default=None,
                        help="door detection: critical points + narrowing test (default) or the paper's band")
    parser.add_argument("--furniture", action="store_true",
                        help="give occupied pixels enclosed by a room (furniture) that room's label")
    parser.add_argument("--steps", action="store_true", help="also write steps.png (a panel per step)")


#: The files ``hsmap segment`` writes into --out.
OUTPUTS = ("rooms.png", "doors.json", "topology.json", "topology.graphml", "topology.txt", "segmentation.png",
           "segmentation_config.yaml", "steps.png")


def run(args: argparse.Namespace) -> int:
    import dataclasses
    import warnings
    from pathlib import Path

    from PIL import Image

    from ..config import dump_config, load_config
    from ..errors import EmptyInputError, HsmapWarning, InputError
    from ..grid import read_map, write_label_image
    from ..io import (
        atomic_path,
        prepare_output_dir,
        refuse_overwriting_input,
        staged_outputs,
        sweep_stale_temporaries,
        write_json,
    )
    from ..segmentation import SegmentationConfig, check_scale, segment_rooms
    from ..topology import room_graph, topology_listing, write_topology
    from ..viz.colors import label_overlay

    if args.resolution is not None and not (args.resolution > 0 and args.resolution < float("inf")):
        raise InputError(f"--resolution must be a finite number > 0 of metres per pixel, got {args.resolution}")
    cfg = load_config(SegmentationConfig, args.config) if args.config else SegmentationConfig()
    if args.method:
        cfg = dataclasses.replace(cfg, method=args.method)
    if args.furniture:
        cfg = dataclasses.replace(cfg, assign_furniture=True)
    refuse_overwriting_input(args.out, [args.map, args.config], OUTPUTS)
    out = prepare_output_dir(args.out, "--out", create=False)
    grid = read_map(args.map, args.resolution)
    try:
        check_scale(grid.free, grid.geometry.resolution, cfg)
    except EmptyInputError as exc:
        raise EmptyInputError(f"{args.map}: {exc}") from None
    except InputError as exc:
        src = "--resolution" if args.resolution is not None else (
            f"{args.map}: 'resolution'" if Path(args.map).suffix.lower() in (".yaml", ".yml")
            else "the default resolution 0.05 (set it with --resolution)")
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
            Image.fromarray(label_overlay(seg.labels, grid.free, doors=seg.doors)).save(tmp, format="PNG")
        dump_config(cfg, stage / "segmentation_config.yaml")
        if args.steps:
            from ..viz.map_figures import voronoi_steps_figure

            fig = voronoi_steps_figure(grid, seg, title=Path(args.map).name)
            with atomic_path(stage / "steps.png") as tmp:
                fig.savefig(tmp, dpi=110)
    print(topology_listing(g), end="")
    print(f"wrote {out}/rooms.png, doors.json, topology.json, topology.graphml, segmentation.png")
    return 0
