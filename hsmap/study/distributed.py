"""One runner for the study's batches of independent jobs on ``dask.distributed``.

A job is a name and a chain of stages (plain functions, each receiving the previous stage's result); each stage is
one Dask task, so a worker that dies mid-stage costs only that stage: the scheduler gives it to another worker
(a stage that raises is retried ``retries`` times). :func:`run_jobs`

- skips a job whose result file (``OUT/NAME/result.json``) says ``"status": "ok"`` (a rerun goes on where the last
  one stopped; failed jobs run again);
- writes each job's result atomically as soon as its last stage finishes, and a failed job's record (its stage and
  error, one line) the same way, while the others go on;
- shows overall progress (one bar, jobs done / failed);
- runs on a ``LocalCluster`` of ``workers`` processes (one thread each) by default, or on an existing cluster
  through its scheduler's address.

The stages read and write files under ``OUT``: with a remote scheduler, the workers must share that folder.
"""

from __future__ import annotations

import json
import time
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import ConfigError, DependencyError
from ..io import write_json

__all__ = ["Job", "run_jobs", "read_result", "RESULT_FILE"]

#: Each job's result file inside ``OUT/NAME/``.
RESULT_FILE = "result.json"


@dataclass
class Job:
    """A named chain of stages: ``stages[0](**kwargs)``, then ``stages[k](previous_result)``.

    Each stage is a picklable (module-level) function; the last returns the job's result, a JSON-able dict.
    """

    name: str
    stages: Sequence[tuple[str, Callable[..., Any]]]
    kwargs: dict = field(default_factory=dict)
    priority: int = 0  # higher first (start the longest jobs early)


def read_result(path: str | Path) -> dict | None:
    """A job's result file, or None when it is missing or unreadable (a half-written file cannot exist: it is
    written atomically)."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _one_line(exc: BaseException) -> str:
    return " ".join(f"{type(exc).__name__}: {exc}".split())


#: Starts of a local cluster tried before giving up (see :func:`_client`).
LOCAL_CLUSTER_TRIES = 3


def _client(workers: int | None, scheduler: str | None):
    try:
        import dask
        from dask.distributed import Client, LocalCluster
    except ImportError as exc:  # pragma: no cover - a dependency of hsmap
        raise DependencyError(f"dask.distributed is needed for the batch ({exc}); pip install 'dask[distributed]'") \
            from None
    if scheduler:
        try:
            return Client(scheduler, timeout="20s"), None
        except (OSError, ValueError, TypeError) as exc:  # unreachable, or not an address (ValueError)
            raise ConfigError(f"--scheduler {scheduler}: cannot reach a Dask scheduler there "
                              f"({' '.join(str(exc).split())[:300]}); expected an address like tcp://HOST:8786") \
                from None
    n = int(workers or 2)
    if n < 1:
        raise ConfigError(f"--workers must be >= 1, got {workers}")
    # The workers start with glibc's own allocator settings. Dask's default sets MALLOC_TRIM_THRESHOLD_, and a
    # fixed threshold turns off glibc's adaptive mmap threshold: every large array is then mapped afresh and its
    # pages faulted in again, which slows the runs (the SLAM runs most). Its thread settings are kept.
    environ = {k: v for k, v in dask.config.get("distributed.nanny.pre-spawn-environ", {}).items()
               if k != "MALLOC_TRIM_THRESHOLD_"}
    # the scheduler, its workers and its dashboard (which has no authentication) listen on loopback only
    for attempt in range(LOCAL_CLUSTER_TRIES):
        try:
            with dask.config.set({"distributed.nanny.pre-spawn-environ": environ}):
                cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                                       dashboard_address="127.0.0.1:0", silence_logs=40)
            break
        except AssertionError:
            # distributed waits a fixed 10 s for its event-loop thread to start and asserts that it did: on a
            # busy machine it may not have, and a new cluster is started
            if attempt == LOCAL_CLUSTER_TRIES - 1:
                raise ConfigError(f"could not start a local Dask cluster: its event loop did not start within "
                                  f"10 s, {LOCAL_CLUSTER_TRIES} times (a busy machine?); run again, or give "
                                  f"--scheduler an address") from None
    return Client(cluster), cluster


def _finished_and_todo(jobs: Sequence[Job], out: Path, skip_finished: bool) -> tuple[dict[str, dict], list[Job]]:
    """The records of the jobs whose result in ``out`` says ok (read back, with ``skip_finished``), and the jobs to
    run."""
    records: dict[str, dict] = {}
    todo = []
    for job in jobs:
        done = read_result(out / job.name / RESULT_FILE)
        if skip_finished and done is not None and done.get("status") == "ok":
            records[job.name] = done | {"skipped": True}
        else:
            todo.append(job)
    return records, todo


def _submit(client, todo: list[Job], out: Path, retries: int) -> tuple[dict, dict[str, list]]:
    """Submit every stage of every job, each stage on its predecessor's result; returns each job's last future
    (future -> job) and each job's (stage, future) list."""
    finals = {}
    stage_of: dict[str, list] = {}
    for job in todo:
        (out / job.name).mkdir(parents=True, exist_ok=True)
        prev = None
        futs = []
        for k, (stage, fn) in enumerate(job.stages):
            key = f"{job.name}/{stage}-{time.time_ns()}"
            if k == 0:
                f = client.submit(_call, fn, job.kwargs, key=key, retries=retries, pure=False,
                                  priority=job.priority)
            else:
                f = client.submit(_call_on, fn, prev, key=key, retries=retries, pure=False,
                                  priority=job.priority)
            futs.append((stage, f))
            prev = f
        finals[prev] = job
        stage_of[job.name] = futs
    return finals, stage_of


def _record(job: Job, fut, stages: list) -> dict:
    """The record of a finished job: its last stage's result, or the stage that failed and why."""
    try:
        result = fut.result()
        return {"name": job.name, "status": "ok", **result}
    except Exception as exc:  # noqa: BLE001 - any failure of a job is recorded, the others go on
        stage = next((s for s, f in stages if f.status == "error"), job.stages[-1][0])
        return {"name": job.name, "status": "failed", "stage": stage, "error": _one_line(exc),
                "traceback": "".join(traceback.format_exception(exc))[-4000:]}


def run_jobs(jobs: Sequence[Job], out: str | Path, *, workers: int | None = 2, scheduler: str | None = None,
             retries: int = 1, progress: bool | None = None, log: Callable[[str], None] | None = None,
             client=None, skip_finished: bool = True) -> list[dict]:
    """Run the jobs (see the module docstring); returns every job's record, in the order of ``jobs``.

    Parameters
    ----------
    jobs : sequence of Job
        Names must be unique (each gets the folder ``out/NAME``).
    out : path
    workers : int
        Processes of the local cluster (ignored with ``scheduler`` or ``client``).
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``).
    retries : int
        Times a stage that raises is tried again (a stage whose worker died is rescheduled by Dask anyway).
    progress : bool or None
        The progress bar (None: on a terminal only).
    log : callable, optional
        Receives one line per finished job.
    client : dask.distributed.Client, optional
        Use this client (tests); it is not closed.
    skip_finished : bool
        Read back jobs whose result says ok instead of running them (False: a benchmark that times this code).

    Returns
    -------
    list of dict
        The records: each has ``name``, ``status`` ("ok" or "failed"; a failed one ``stage`` and ``error``),
        ``skipped`` (True when read back from an earlier run) and whatever the last stage returned.
    """
    from tqdm.auto import tqdm

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    names = [j.name for j in jobs]
    if len(set(names)) != len(names):
        raise ConfigError(f"job names must be unique, got {names}")
    records, todo = _finished_and_todo(jobs, out, skip_finished)
    bar = tqdm(total=len(jobs), initial=len(jobs) - len(todo), unit="job", desc="jobs",
               disable=None if progress is None else not progress)
    if not todo:
        bar.close()
        return [records[n] for n in names]

    own_client, own_cluster = client is None, None
    if own_client:
        client, own_cluster = _client(workers, scheduler)
    try:
        from dask.distributed import as_completed

        finals, stage_of = _submit(client, todo, out, retries)
        failed = 0
        for fut in as_completed(list(finals)):
            job = finals[fut]
            t = time.time()
            rec = _record(job, fut, stage_of[job.name])
            failed += rec["status"] != "ok"
            rec["finished"] = time.strftime("%Y-%m-%dT%H:%M:%S", time.localtime(t))
            write_json(out / job.name / RESULT_FILE, rec)
            records[job.name] = rec | {"skipped": False}
            bar.update(1)
            bar.set_postfix_str(f"{failed} failed" if failed else "")
            if log is not None:
                log(f"{job.name}: {rec['status']}" + (f" ({rec['stage']}: {rec['error']})"
                                                     if rec["status"] != "ok" else ""))
    finally:
        bar.close()
        if own_client:
            client.close()
            if own_cluster is not None:
                own_cluster.close()
    return [records[n] for n in names]


def _call(fn: Callable[..., Any], kwargs: dict) -> Any:
    return fn(**kwargs)


def _call_on(fn: Callable[..., Any], previous: Any) -> Any:
    return fn(previous)
