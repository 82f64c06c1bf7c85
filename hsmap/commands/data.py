"""The public benchmark data of the study: the Freiburg SLAM benchmark logs (Kümmerle et al. 2009) and the room
segmentation maps of Bormann et al. 2016, OctoMap's 3D map of Freiburg building 079 (Hornung et al. 2013), and
BALM's 177 real sweeps of a hand-held 3D LiDAR (Liu et al. 2023; laid out as hsmap reads it: times.txt and
groundtruth.tum beside the clouds).
'hsmap data fetch' downloads them from their original public
repositories (pinned commits), checks each file's SHA-256 and stores them in hsmap's user cache, where notebook
08, the tests and the benchmark scripts find them; $HSMAP_DATASETS, when set, is used instead. A file whose hash
differs is refused and not stored. $HSMAP_DATA_MIRROR (or --mirror) replaces the original URLs with one base URL
serving the same layout (slam2d/..., ipa_room_segmentation/..., octomap/..., balm/...)."""

from __future__ import annotations

import argparse

NAME = "data"
HELP = "download the public benchmark data (hash-checked) into the user cache, or list it"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    p = sub.add_parser("fetch", help="download the public datasets (default: all) and check their SHA-256")
    p.add_argument("names", nargs="*", metavar="NAME", help="freiburg, bormann, octomap and/or balm (default: all)")
    p.add_argument("--mirror", metavar="URL",
                   help="base URL serving the datasets layout, instead of the original URLs "
                        "(default $HSMAP_DATA_MIRROR)")
    p.add_argument("--dest", metavar="DIR",
                   help="download folder (default: datasets/ in the user cache, $HSMAP_CACHE or ~/.cache/hsmap)")
    p.set_defaults(_action=_fetch)
    p = sub.add_parser("list", help="the public datasets, their sources and where they are found")
    p.set_defaults(_action=_list)


def run(args: argparse.Namespace) -> int:
    return args._action(args)


def _fetch(args: argparse.Namespace) -> int:
    from ..study.public_data import fetch, fetch_dir

    if args.dest is not None:  # named by its flag here, before any download
        from ..errors import InputError
        from ..io import resolved

        target = resolved(args.dest, "--dest")
        if target.exists() and not target.is_dir():
            raise InputError(f"--dest {args.dest}: exists and is not a folder")
    dest = args.dest or fetch_dir()
    results = fetch(args.names or None, dest=dest, mirror=args.mirror, log=lambda line: print(line, flush=True))
    for r in results:
        done = (f"{len(r.downloaded)} downloaded" + (f", {len(r.replaced)} damaged copies replaced" if r.replaced
                                                     else "") + f", {len(r.present)} already there")
        nbytes = sum((r.folder / f.path).stat().st_size for f in r.dataset.files)
        print(f"{r.dataset.name}: {len(r.dataset.files)} files, {nbytes / 1e6:.1f} MB, SHA-256 ok "
              f"({done}) in {r.folder}")
        print(f"  cite: {' '.join(r.dataset.citation.split())}")
    import os

    if os.environ.get("HSMAP_DATASETS"):
        print(f"note: HSMAP_DATASETS={os.environ['HSMAP_DATASETS']} is set and is used instead of {dest}")
    return 0


def _list(args: argparse.Namespace) -> int:
    from ..study.paths import datasets_dir
    from ..study.public_data import dataset_folder, registry

    root = datasets_dir()
    print(f"datasets folder: {root}")
    for ds in registry().values():
        folder = dataset_folder(ds.name, root)
        where = f"present in {folder}" if folder else "missing (hsmap data fetch " + ds.name + ")"
        size = "" if ds.size is None else f", {ds.size / 1e6:.1f} MB"
        print(f"{ds.name}: {ds.title}; {len(ds.files)} files{size}; {where}")
        for s in ds.sources:
            print(f"  source: {s}")
    return 0
