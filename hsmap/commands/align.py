"""Register a 2D map onto a 3D map's height band with no initial guess, and overlay them.

MAP2D is a map_server YAML (with its image), a map image (PNG/PGM; >= 250 free, --resolution metres per pixel,
default 0.05), or a 2D point map (.ply/.pcd, e.g. the map.ply of ``hsmap slam --dof 3``: its points are the
occupied cells). MAP3D is an OctoMap .bt/.ot or a .ply/.pcd point map, cut at --band LO,HI metres above its floor
(as ``hsmap segment MAP3D --band``), or a 2D map like MAP2D. The search is exhaustive over every rotation and
every translation that makes the maps overlap (both ways), refined by Harmony-ICP (``hsmap.maps.fusion.global_align``).
Writes into --out: alignment.json (the MAP2D -> MAP3D transform, overlap, residual, the search's candidates and
which part of each map the other covers), overlay.png (both maps in MAP3D's frame: structure seen by both dark,
by MAP2D only red, by MAP3D only blue) and the aligned grids (map2d_aligned.yaml/.pgm, map3d_band.yaml/.pgm).
A match the search cannot tell from another pose in either direction (the best pose more than 2 m away scores at
least 0.9 of the found one's, the rule of HS-SLAM's far loop closures) is refused: exit status 2, nothing written.
"""

from __future__ import annotations

import argparse

NAME = "align"
HELP = "register a 2D map onto a 3D map's height band (no initial guess) and overlay them"

#: The files ``hsmap align`` writes into --out.
OUTPUTS = ("alignment.json", "overlay.png", "map2d_aligned.yaml", "map2d_aligned.pgm", "map3d_band.yaml",
           "map3d_band.pgm")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("map2d", metavar="MAP2D", help="2D map: map_server YAML, image, or .ply/.pcd points")
    parser.add_argument("map3d", metavar="MAP3D", help="3D map (.bt, .ot, .ply, .pcd) or a 2D map")
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--band", metavar="LO,HI", default="1.7,1.8",
                        help="height band of MAP3D in metres above its floor (default 1.7,1.8)")
    parser.add_argument("--floor", type=float, default=None, metavar="Z",
                        help="MAP3D's floor height (default: found in the map)")
    parser.add_argument("--resolution", type=float, default=None,
                        help="metres per pixel of a MAP2D image (default 0.05) or cell of MAP2D points")
    parser.add_argument("--seed", type=int, default=1, help="seed of the Harmony-ICP refinement (default 1)")


def _points_grid(path, resolution: float):
    """A 2D point map as an occupancy grid (its points' cells occupied, the rest unknown) and its points."""
    import numpy as np

    from ..datasets.clouds import read_points
    from ..errors import EmptyInputError
    from ..maps.grid import OCCUPIED, UNKNOWN, GridGeometry, OccupancyGrid

    pts = read_points(path)[:, :2]
    if len(pts) < 3:
        raise EmptyInputError(f"{path}: {len(pts)} points; a 2D point map needs at least 3")
    geo = GridGeometry.covering(pts.min(axis=0), pts.max(axis=0), resolution, margin=0.5)
    data = np.full(geo.shape, UNKNOWN, dtype=np.int8)
    rc = geo.world_to_index(pts)
    data[rc[:, 0], rc[:, 1]] = OCCUPIED
    return OccupancyGrid(data, geo), pts


def _read_2d(path: str, resolution: float | None):
    from pathlib import Path

    from ..errors import InputError
    from ..maps.grid import read_map

    if Path(path).suffix.lower() in (".bt", ".ot"):
        raise InputError(f"MAP2D {path}: an OctoMap 3D map; MAP2D takes a 2D map (map_server YAML, PNG/PGM image, "
                         ".ply/.pcd points): give the 3D map as MAP3D")
    if Path(path).suffix.lower() in (".ply", ".pcd"):
        return _points_grid(path, 0.05 if resolution is None else resolution)
    return read_map(path, resolution), None


def _map_files(path: str) -> list[str]:
    """A map's file and, for a map_server YAML, the image it names (both are inputs an output must not replace)."""
    from pathlib import Path

    from ..limits import load_yaml, read_bounded

    files = [path]
    p = Path(path)
    if p.suffix.lower() in (".yaml", ".yml") and p.is_file():
        try:
            meta = load_yaml(read_bounded(p, "map_server YAML").decode("utf-8"))
        except Exception:  # noqa: BLE001 - the map's reader names what is wrong with it
            return files
        if isinstance(meta, dict) and isinstance(meta.get("image"), str):
            files.append(str(p.parent / meta["image"]))
    return files


def _check_unique(candidates: list[dict], map2d: str, map3d: str) -> None:
    """Refuse a match the search cannot tell from another pose: in both directions the best pose elsewhere (more
    than the search's separation away) scores at least ``LoopClosureConfig.far_ambiguity`` (0.9) of the found
    pose's score, the rule HS-SLAM's far loop closures use. Then the maps show no common place, or MAP2D holds too
    little structure to place it (a blob fits any wall)."""
    from ..errors import DegenerateInputError
    from ..slam.loopclosure import LoopClosureConfig

    limit = LoopClosureConfig().far_ambiguity
    amb = [float(c["ambiguity"]) for c in candidates]
    if min(amb) >= limit:
        raise DegenerateInputError(
            f"{map2d} onto {map3d}: no unique match (the best pose elsewhere scores {amb[0]:.2f} of the found one's "
            f"with MAP2D searched in MAP3D and {amb[1]:.2f} the other way; a match needs one under {limit:g}): the "
            "maps may not show the same place, or MAP2D holds too little structure to place it")


def _covered(grid, other_geo, T) -> dict:
    """Which part of ``grid``'s occupied cells lie inside the box of ``other_geo`` after moving by ``T``."""

    from ..maps.fusion import occupied_points

    pts = occupied_points(grid)
    moved = pts @ T[:2, :2].T + T[:2, 2]
    x0, x1, y0, y1 = other_geo.extent()
    inside = (moved[:, 0] >= x0) & (moved[:, 0] <= x1) & (moved[:, 1] >= y0) & (moved[:, 1] <= y1)
    out = {"occupied_cells": int(len(pts)), "inside_other_box": float(inside.mean()) if len(pts) else 0.0}
    if inside.any():
        lo, hi = pts[inside].min(axis=0), pts[inside].max(axis=0)
        out["inside_box_own_frame"] = {"x": [float(lo[0]), float(hi[0])], "y": [float(lo[1]), float(hi[1])]}
    return out


def run(args: argparse.Namespace) -> int:
    import math
    from pathlib import Path

    import numpy as np
    from PIL import Image

    from ..errors import InputError
    from ..io import (
        atomic_path,
        prepare_output_dir,
        refuse_overwriting_input,
        staged_outputs,
        sweep_stale_temporaries,
        write_json,
    )
    from ..maps.fusion import FusionConfig, GlobalSearch, global_align, resample_grid
    from ..maps.grid import read_map, write_map
    from ..maps.maps3d import band_grid, floor_height, read_map3d
    from .inputs import parse_vector

    if args.resolution is not None and not (math.isfinite(args.resolution) and args.resolution > 0):
        raise InputError(f"--resolution must be a finite number > 0 of metres, got {args.resolution}")
    if args.floor is not None and not math.isfinite(args.floor):
        raise InputError(f"--floor must be a finite height in metres, got {args.floor}")
    if args.seed < 0:
        raise InputError(f"--seed must be >= 0, got {args.seed}")
    lo, hi = parse_vector(args.band, 2, "--band")
    if not lo < hi:
        raise InputError(f"--band must be LO,HI with LO < HI, got {args.band!r}")
    refuse_overwriting_input(args.out, [*_map_files(args.map2d), *_map_files(args.map3d)], OUTPUTS)
    out = prepare_output_dir(args.out, "--out", create=False)
    map2d, points2d = _read_2d(args.map2d, args.resolution)
    band = None
    if Path(args.map3d).suffix.lower() in (".bt", ".ot", ".ply", ".pcd"):
        m = read_map3d(args.map3d)
        floor = floor_height(m) if args.floor is None else float(args.floor)
        target = band_grid(m, lo, hi, floor=floor)
        band = {"floor": floor, "band": [float(lo), float(hi)], "resolution": m.resolution}
    else:
        target = read_map(args.map3d)
    cfg = FusionConfig()
    al, candidates = global_align(map2d, target, floor_points=points2d, config=cfg, search=GlobalSearch(),
                                  rng=args.seed)
    _check_unique(candidates, args.map2d, args.map3d)
    T = al.transformation
    reg = al.registration
    result = {
        "map2d": str(args.map2d),
        "map3d": str(args.map3d),
        "band": band,
        "seed": args.seed,
        "transform": {"x": float(al.pose[0]), "y": float(al.pose[1]), "yaw_deg": float(np.rad2deg(al.pose[2])),
                      "matrix": T.tolist(),
                      "meaning": "MAP2D frame -> MAP3D frame: p3d = R(yaw) p2d + (x, y)"},
        "overlap": {"overlap": al.overlap, "map2d_matched": al.floor_matched, "map3d_matched": al.slice_matched,
                    "tolerance": al.tolerance},
        "residual": {"rmse": reg.rmse, "inlier_ratio": reg.inlier_ratio, "fitness": reg.fitness,
                     "inlier_distance": cfg.registration.threshold, "cost": reg.cost},
        "coverage": {"map2d_in_map3d": _covered(map2d, target.geometry, T),
                     "map3d_in_map2d": _covered(target, map2d.geometry, np.linalg.inv(T))},
        "candidates": candidates,
        "seconds": reg.seconds,
    }
    sweep_stale_temporaries(out, OUTPUTS)
    with staged_outputs(out) as stage:
        write_json(stage / "alignment.json", result)
        img = al.overlay()
        scale = max(1, int(round(1600 / max(img.shape[:2]))))
        with atomic_path(stage / "overlay.png") as tmp:
            Image.fromarray(img).resize((img.shape[1] * scale, img.shape[0] * scale), Image.NEAREST).save(
                tmp, format="PNG")
        write_map(stage / "map2d_aligned.yaml", al.floor)
        write_map(stage / "map3d_band.yaml", resample_grid(target, target=al.slice.geometry))
    t = result["transform"]
    ov = result["overlap"]
    print(f"MAP2D -> MAP3D: x {t['x']:.3f} m, y {t['y']:.3f} m, yaw {t['yaw_deg']:.3f} deg; overlap "
          f"{ov['overlap']:.3f} (MAP2D matched {ov['map2d_matched']:.3f}, MAP3D matched {ov['map3d_matched']:.3f} "
          f"within {ov['tolerance']:g} m); residual rmse {reg.rmse:.3f} m, inliers {reg.inlier_ratio:.3f}")
    print(f"wrote {out}/alignment.json, overlay.png, map2d_aligned.yaml, map3d_band.yaml")
    return 0
