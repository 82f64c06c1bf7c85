"""Evaluate results against ground truth; prints one JSON object of metrics on stdout."""

from __future__ import annotations

import argparse
import json
import sys

NAME = "evaluate"
HELP = "score a trajectory or a segmentation against ground truth (JSON on stdout)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="what", metavar="WHAT", required=True)
    p = sub.add_parser("relations", help="Freiburg relations metric (Kümmerle et al. 2009)")
    p.add_argument("trajectory", help="estimated trajectory, TUM format")
    p.add_argument("relations", help="ground-truth .relations file")
    p.add_argument("--skip-unmatched", action="store_true",
                   help="score only the relations whose stamps lie within the trajectory's time span (a partial "
                        "run, e.g. hsmap slam --max-frames); the output says how many were used")
    p.set_defaults(_evaluate=_relations)
    p = sub.add_parser("trajectory", help="per-DOF errors, ATE and RPE against a ground-truth trajectory")
    p.add_argument("estimate", help="estimated trajectory, TUM format")
    p.add_argument("groundtruth", help="ground-truth trajectory, TUM format")
    p.set_defaults(_evaluate=_trajectory)
    p = sub.add_parser("segmentation", help="Bormann et al. 2016 precision and recall of a room segmentation")
    p.add_argument("rooms", help="room label image (PNG, 0 = no room)")
    p.add_argument("groundtruth", help="ground-truth segmentation image (rooms are regions of pixels > 250)")
    p.set_defaults(_evaluate=_segmentation)


def run(args: argparse.Namespace) -> int:
    metrics = args._evaluate(args)
    json.dump(metrics, sys.stdout, indent=2)
    sys.stdout.write("\n")
    return 0


def _relations(args: argparse.Namespace) -> dict:
    """Freiburg relations metric of a TUM trajectory against a ``.relations`` file."""
    from ..datasets.relations import read_relations
    from ..evaluation.trajectory import relations_error
    from ..trajectory import read_tum

    traj = read_tum(args.trajectory)
    relations = read_relations(args.relations)
    result = relations_error(traj, relations, skip_unmatched=args.skip_unmatched).as_dict()
    return {"trajectory": str(args.trajectory), "relations": str(args.relations), **result}


def _trajectory(args: argparse.Namespace) -> dict:
    """Per-DOF errors (relative to the first pose), ATE and RPE of a TUM estimate against a TUM ground truth."""
    from ..evaluation.trajectory import evaluate_trajectory
    from ..trajectory import read_tum

    est = read_tum(args.estimate)
    ref = read_tum(args.groundtruth)
    return {"estimate": str(args.estimate), "groundtruth": str(args.groundtruth), **evaluate_trajectory(est, ref)}


def _segmentation(args: argparse.Namespace) -> dict:
    from ..evaluation.segmentation import segmentation_scores
    from ..maps.grid import read_image_gray, read_label_image

    labels = read_label_image(args.rooms)
    gt = read_image_gray(args.groundtruth)
    scores = segmentation_scores(labels, gt)
    out = {"rooms": str(args.rooms), "groundtruth": str(args.groundtruth)}
    out.update(scores.as_dict())
    return out
