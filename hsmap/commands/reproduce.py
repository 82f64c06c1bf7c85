"""Run the study: every notebooks/NN-name.ipynb executed by papermill into reports/ (executed notebook,
HTML report, figures, metrics.json, rerun recordings) and reports/index.html listing them all with their
headline numbers beside the paper's. It prints a line when each notebook starts and ends and, in between, at
least every 30 s which notebooks run, at which cell, for how long. A failing notebook does not stop the others;
the command exits 1 when any notebook failed. A notebook's previous report is replaced only by a complete new one (an interrupted run
leaves it as it was), and two batches into the same folder keep each other's entries in the index.

First the public data the notebooks read (the Freiburg logs, Bormann's maps, the OctoMap map: ``hsmap data
list``) that is missing is downloaded (``hsmap data fetch``, hash-checked, into the user cache); with no network
the run goes on and the notebooks lacking data skip, saying why. With $HSMAP_DATASETS set nothing is downloaded
(that folder is the only one looked at). The step runs for the study's own notebooks, not for another folder
given with --notebooks; --no-fetch skips it."""

from __future__ import annotations

import argparse
import sys

NAME = "reproduce"
HELP = "run the study notebooks with papermill into reports/ (index.html, HTML reports, metrics, .rrd)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true",
                        help="small inputs for a smoke run (passes quick=True to every notebook)")
    parser.add_argument("--only", nargs="+", action="extend", metavar="NAME",
                        help="run only these notebooks (full name '03-hs-slam-6dof', short name 'hs-slam-6dof' or "
                             "number '3'); the index keeps the others' last results")
    parser.add_argument("--jobs", "-j", type=int, default=1, metavar="N",
                        help="notebooks run at once, each in its own process (default 1)")
    parser.add_argument("--out", default="reports", metavar="DIR", help="reports folder (default reports/)")
    parser.add_argument("--notebooks", default=None, metavar="DIR",
                        help="folder of the study notebooks (default notebooks/ here, else the checkout's, else "
                             "the ones installed with hsmap)")
    parser.add_argument("-p", "--parameter", nargs=2, action="append", default=[], metavar=("KEY", "VALUE"),
                        help="extra parameter for every notebook, VALUE read as YAML (repeatable)")
    parser.add_argument("--parameters-file", metavar="YAML",
                        help="YAML with 'parameters:' (every notebook) and 'notebooks: {NAME: {...}}'")
    parser.add_argument("--timeout", type=float, default=None, metavar="S",
                        help="time limit per notebook cell in seconds (default: none)")
    parser.add_argument("--no-verify", action="store_true",
                        help="do not check the recordings with 'rerun rrd verify'")
    parser.add_argument("--list", action="store_true",
                        help="list the notebooks and their parameters, run nothing")
    parser.add_argument("--no-fetch", action="store_true",
                        help="do not download missing public data first (hsmap data fetch)")


def fetch_missing(log, fetch=None) -> dict[str, str]:
    """Download the public datasets missing from :func:`hsmap.study.paths.datasets_dir` (see the module
    docstring); a failed download is logged and the run goes on.

    Parameters
    ----------
    log : callable
        Receives one line per dataset fetched, failed or left missing.
    fetch : callable, optional
        ``fetch(names, dest=..., log=...)`` as :func:`hsmap.study.public_data.fetch` (the default).

    Returns
    -------
    dict of str to str
        Dataset name -> "present", "fetched", "failed: REASON" or "missing: REASON".
    """
    import os

    from ..errors import HsmapError
    from ..study.paths import DATASETS_ENV, datasets_dir
    from ..study.public_data import dataset_folder, fetch_dir, registry

    if fetch is None:
        from ..study.public_data import fetch
    root = datasets_dir()
    status = {name: "present" for name in registry() if dataset_folder(name, root) is not None}
    missing = [name for name in registry() if name not in status]
    if not missing:
        return status
    if os.environ.get(DATASETS_ENV):
        for name in missing:
            status[name] = f"missing: not in ${DATASETS_ENV}={root} (nothing is downloaded while it is set)"
            log(f"data: {name} {status[name]}")
        return status
    dest = fetch_dir()
    # the download folder becomes the datasets folder once it holds anything: it gets the whole set
    wanted = [name for name in registry() if dataset_folder(name, dest) is None]
    for name in wanted:
        try:
            fetch([name], dest=dest, log=log)
            status[name] = "fetched"
            log(f"data: {name} fetched into {dest}")
        except (HsmapError, OSError) as exc:
            status[name] = f"failed: {' '.join(str(exc).split())}"
            log(f"data: {name} could not be fetched ({status[name][8:]}); the notebooks needing it skip")
    return status


def _notebooks_dir(arg: str | None):
    from pathlib import Path

    from ..study.paths import notebooks_dir

    if arg is not None:
        return Path(arg)
    here = Path("notebooks")
    if here.is_dir():
        return here
    return notebooks_dir()  # the checkout's, else the ones installed with hsmap


def _list(notebooks_dir, only) -> int:
    from ..study.batch import discover, inspect_parameters, require_study_tooling, select

    require_study_tooling()
    specs = select(discover(notebooks_dir), only)
    if not specs:
        print(f"no study notebooks (NN-name.ipynb) in {notebooks_dir}")
        return 0
    for s in specs:
        print(f"{s.name}  ({s.title()})")
        params = inspect_parameters(s)
        if not params:
            print("    (no parameters cell)")
        for p in params.values():
            typ = p.get("inferred_type_name") or "None"
            line = f"    {p['name']}: {typ} = {p['default']}"
            if p.get("help"):
                line += f"    # {p['help']}"
            print(line)
    return 0


def run(args: argparse.Namespace) -> int:
    from ..io import prepare_output_dir
    from ..progress import reporting
    from ..study.batch import run_notebooks
    from ..study.discovery import load_parameters_file, parse_value

    notebooks_dir = _notebooks_dir(args.notebooks)
    if args.list:
        return _list(notebooks_dir, args.only)
    prepare_output_dir(args.out, "--out", create=False)

    def log(line: str) -> None:
        print(line, flush=True)

    if not args.no_fetch and args.notebooks is None:
        fetch_missing(log)
    common, per = ({}, {})
    if args.parameters_file:
        common, per = load_parameters_file(args.parameters_file)
    for key, value in args.parameter:
        common[key] = parse_value(value)

    # a line when each notebook starts and ends, and a heartbeat (which notebooks, which cell, how long) between
    with reporting(log):
        result = run_notebooks(
            notebooks_dir, args.out, only=args.only, quick=args.quick, jobs=args.jobs, parameters=common,
            notebook_parameters=per, timeout=args.timeout, verify_recordings=not args.no_verify, log=log,
        )
    from ..study.report import format_duration

    n = len(result.runs)
    skipped = f", {len(result.skipped)} skipped (inputs missing)" if result.skipped else ""
    print(f"{n - len(result.failed) - len(result.skipped)} of {n} notebooks ok{skipped} in "
          f"{format_duration(result.duration_s)}; index: {result.index}")
    if result.failed:
        print("failed: " + ", ".join(r.name for r in result.failed), file=sys.stderr)
        return 1
    return 0
