"""The input options ``hsmap slam`` and ``hsmap map`` share: which topics, frames, offsets and stamps to read.

Not a sub-command: :func:`add_input_arguments` adds the flags, :func:`open_input` opens the input with them, and
every message of the readers names these flags (``--scan-topic``, not the Python ``scan_topic``).
"""

from __future__ import annotations

import argparse

#: The readers' option names -> this command line's flags (used in every message).
FLAGS = {
    "scan_topic": "--scan-topic", "cloud_topic": "--cloud-topic", "odom_topic": "--odom-topic",
    "base_frame": "--base-frame", "extrinsic2d": "--extrinsic2d", "extrinsic3d": "--extrinsic3d",
    "sync_tolerance": "--sync-tolerance", "cloud_rate": "--cloud-rate", "scans": "--scans",
    "scan_rate": "--scan-rate", "drive": "--dof", "times": "--times",
}

INPUT_HELP = ("simulator folder (dataset.yaml), ROS1 .bag, ROS2 bag folder or lone .mcap/.db3 file, CARMEN log "
              "(.log/.clf, optionally .gz), or a folder of .pcd/.ply/KITTI .bin/.csv clouds (in natural order of "
              "their names: full2 before full10; stamps from a times.txt there, --times or --cloud-rate)")


def add_input_arguments(parser: argparse.ArgumentParser) -> None:
    """The flags that say how to read the input (each independent of the others)."""
    g = parser.add_argument_group("input (bags: topics, frames, offsets; cloud folders: stamps and 2D scans)")
    g.add_argument("--scan-topic", help="bag topic of the 2D LaserScan (default: the only one; '' for none)")
    g.add_argument("--cloud-topic", help="bag topic of the 3D PointCloud2 (default: the only one; '' for none)")
    g.add_argument("--odom-topic", help="bag topic of the Odometry (default: the only one; '' for none)")
    g.add_argument("--base-frame", help="robot base frame of the sensor offsets (default: the odometry's child "
                                        "frame, else base_link or base_footprint); heights are measured from its "
                                        "z = 0, so prefer a frame on the floor")
    g.add_argument("--extrinsic2d", metavar="X,Y,YAW",
                   help="pose of the 2D LiDAR in the robot base frame (metres, radians), overriding the input's "
                        "(TF, a log's PARAM); without it and without TF the offset is zero, with a warning")
    g.add_argument("--extrinsic3d", metavar="X,Y,Z,ROLL,PITCH,YAW",
                   help="pose of the 3D LiDAR in the robot base frame (metres, radians), overriding the input's; a "
                        "folder of clouds alone is posed in the LiDAR's own frame (zero, no warning) without it")
    g.add_argument("--sync-tolerance", type=float, metavar="S",
                   help="seconds: the largest gap between a frame and the other sensor's message attached to it, "
                        "and between a cloud and the 2D poses interpolated for it, unless those are two consecutive poses of "
                        "the 2D run's regular cadence (default 0.1)")
    g.add_argument("--times", metavar="FILE",
                   help="cloud folders: the clouds' stamps (s), one a line or a TUM trajectory (its first column), "
                        "one per cloud file in natural order, instead of a times.txt in the folder")
    g.add_argument("--cloud-rate", type=float, metavar="HZ",
                   help="cloud folders: the clouds' rate (file k at k / HZ s) instead of a times.txt")
    g.add_argument("--scans", metavar="DIR", help="cloud folders: a folder of 2D scans (points in the 2D "
                                                  "sensor's frame, same file kinds)")
    g.add_argument("--scan-rate", type=float, metavar="HZ", help="cloud folders: the 2D scans' rate instead of "
                                                                 "their times.txt")


def parse_vector(text: str, n: int, flag: str):
    """``"a,b,c"`` -> n floats; an :class:`hsmap.errors.InputError` naming ``flag`` otherwise."""
    import numpy as np

    from ..errors import InputError

    parts = [p.strip() for p in str(text).split(",")]
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise InputError(f"{flag} must be {n} comma-separated numbers, got {text!r}") from None
    if len(values) != n or not np.all(np.isfinite(values)):
        raise InputError(f"{flag} must be {n} comma-separated finite numbers, got {text!r}")
    return np.asarray(values)


#: Largest sensor offset from the robot's base (metres) and largest angle (radians: a full turn) an extrinsic
#: flag takes.
MAX_OFFSET, MAX_ANGLE = 100.0, 6.2832


def _extrinsic(text: str, n: int, flag: str):
    """An extrinsic flag's pose (metres, radians): each offset within :data:`MAX_OFFSET` of the robot's base,
    its angles within :data:`MAX_ANGLE`; an :class:`hsmap.errors.InputError` naming ``flag`` otherwise."""
    import numpy as np

    from ..errors import InputError

    v = parse_vector(text, n, flag)
    t, a = (v[:2], v[2:]) if n == 3 else (v[:3], v[3:])
    if np.abs(t).max() > MAX_OFFSET or np.abs(a).max() > MAX_ANGLE:
        raise InputError(f"{flag}: a sensor offset of up to {np.abs(t).max():.3g} m, angles up to "
                         f"{np.abs(a).max():.3g} rad; expected at most {MAX_OFFSET:g} m and {MAX_ANGLE:g} rad (a "
                         f"full turn), got {text!r}")
    return v


def sync_tolerance(args: argparse.Namespace) -> float | None:
    """``--sync-tolerance``, checked."""
    import math

    from ..errors import InputError

    tol = args.sync_tolerance
    if tol is not None and not (math.isfinite(tol) and tol >= 0):
        raise InputError(f"--sync-tolerance must be a number of seconds >= 0, got {tol}")
    return tol


def open_input(args: argparse.Namespace, drive: str | None = None, progress: bool | None = None):
    """The input opened with the flags of :func:`add_input_arguments` (``drive``: which sensor makes the frames)."""
    from ..datasets.open import open_dataset

    ext2 = None if args.extrinsic2d is None else _extrinsic(args.extrinsic2d, 3, "--extrinsic2d")
    ext3 = None if args.extrinsic3d is None else _extrinsic(args.extrinsic3d, 6, "--extrinsic3d")
    return open_dataset(args.input, scan_topic=args.scan_topic, cloud_topic=args.cloud_topic,
                        odom_topic=args.odom_topic, base_frame=args.base_frame, extrinsic2d=ext2, extrinsic3d=ext3,
                        sync_tolerance=sync_tolerance(args), drive=drive, cloud_rate=args.cloud_rate,
                        scans=args.scans, scan_rate=args.scan_rate, times=args.times, option_names=FLAGS,
                        progress=progress)


def slam_overrides(cfg, args: argparse.Namespace, *, deskew: bool = False):
    """``cfg`` (a :class:`~hsmap.slam.SlamConfig`) with the command line's SLAM flags applied: ``--dof`` (where the
    command has it), ``--no-odometry``, ``--no-loop-closure``, ``--sync-tolerance`` and, with ``deskew`` (the
    configurations of timed clouds and scans), ``--no-deskew``."""
    import dataclasses

    if getattr(args, "dof", None) is not None:
        cfg = dataclasses.replace(cfg, dof=args.dof)  # validated like any SlamConfig
    if args.no_odometry:
        cfg = dataclasses.replace(cfg, use_odometry=False)
    if args.no_loop_closure:
        cfg = dataclasses.replace(cfg, loop_closure=dataclasses.replace(cfg.loop_closure, enabled=False))
    if deskew and getattr(args, "no_deskew", False):
        cfg = dataclasses.replace(cfg, deskew=False)
    tol = sync_tolerance(args)
    if tol is not None:
        cfg = dataclasses.replace(cfg, sync_tolerance=tol)
    return cfg
