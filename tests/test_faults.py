"""Fault injection: disk full during each output, SIGINT, SIGTERM and SIGKILL during ``hsmap slam`` and
``hsmap reproduce``, two ``hsmap reproduce`` at once.

Every fault must end the same way: the previous good outputs intact (byte for byte), no temporary file left
behind (after the next run, for a SIGKILL, which leaves no chance to clean up), no output that looks complete but
is not, and on the command line one line ``hsmap: error: ...`` (exit 2) or ``hsmap: interrupted`` (exit 130).

Disk full is injected four ways: writers that fail half-way (a Python writer raising ENOSPC, Open3D and rerun
files cut short without a word, as those libraries do on a full disk, and the recording's byte stream failing
after any number of bytes); ``os.fsync`` failing with ENOSPC on the k-th file a command writes, for every k (each
output of ``hsmap slam``, ``segment``, ``simulate`` and ``reproduce`` and of a study cache fill in turn); and,
where the machine allows a mount, a real tmpfs of 1 MiB filled to a few kilobytes (skipped with the reason where
not). Signals are sent when the run has reached the point under test (the run, stopped there by the test, writes
a marker file), never after a guessed delay.
"""

from __future__ import annotations

import errno
import json
import os
import re
import shutil
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from hsmap.cli import main
from hsmap.errors import OutputError
from hsmap.testing import room_scan_sequence, write_scan_bag

SLAM_OUTPUTS = ["config.yaml", "map.ply", "metrics.json", "slam.rrd", "trajectory.tum"]


# --- helpers -------------------------------------------------------------------------------------------------------


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (hidden ones included) and its bytes."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def hidden(folder: Path) -> list[str]:
    """Temporaries: anything under ``folder`` whose name starts with a dot."""
    return [str(p.relative_to(folder)) for p in folder.rglob(".*")]


def one_error_line(err: str) -> str:
    lines = [line for line in err.splitlines() if not line.startswith("hsmap: warning:")]
    assert len(lines) == 1 and lines[0].startswith("hsmap: error: "), err
    return lines[0]


@pytest.fixture(scope="module")
def bag(tmp_path_factory) -> Path:
    r, a, _ = room_scan_sequence(12, 0.05, beams=271)
    return write_scan_bag(tmp_path_factory.mktemp("bag") / "room.bag", r, 100.0 + 0.1 * np.arange(len(r)),
                          angle_min=a[0], angle_increment=a[1] - a[0])


def slam(bag: Path, out: Path, *extra: str) -> int:
    return main(["slam", str(bag), "--out", str(out), "--quiet", *extra])


@pytest.fixture(scope="module")
def previous(bag, tmp_path_factory) -> dict[str, bytes]:
    """A complete earlier run's folder, to be copied where a faulty run then writes."""
    out = tmp_path_factory.mktemp("previous") / "out"
    assert slam(bag, out, "--seed", "3") == 0
    files = snapshot(out)
    assert sorted(files) == SLAM_OUTPUTS
    return files


def lay(files: dict[str, bytes], folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for name, data in files.items():
        (folder / name).write_bytes(data)
    return folder


class FsyncFails:
    """``os.fsync`` that fails with ENOSPC on the k-th regular file (as a full disk reports at the flush): each
    file an hsmap command publishes is synced once, so k walks through its outputs."""

    def __init__(self, monkeypatch, k: int):
        self.k, self.files, self.real = k, [], os.fsync
        monkeypatch.setattr(os, "fsync", self)

    def __call__(self, fd: int) -> None:
        if stat.S_ISREG(os.fstat(fd).st_mode):
            self.files.append(os.readlink(f"/proc/self/fd/{fd}") if os.path.exists("/proc/self/fd") else fd)
            if len(self.files) == self.k:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self.real(fd)


# --- writers that fail half-way ------------------------------------------------------------------------------------


def test_a_writer_failing_half_way_publishes_nothing_and_says_which_output(tmp_path):
    from hsmap.io import atomic_open, atomic_path

    target = tmp_path / "out.json"
    target.write_text("previous")
    with pytest.raises(OutputError, match=f"{target}: cannot write it \\(No space left on device\\)"):
        with atomic_open(target) as fh:
            fh.write("half of it")
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    assert target.read_text() == "previous" and hidden(tmp_path) == []
    with pytest.raises(OutputError, match="cannot write it"), atomic_path(tmp_path / "x.png") as tmp:
        tmp.write_bytes(b"\x89PNG")
        raise OSError(errno.EROFS, os.strerror(errno.EROFS))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]


def test_silently_cut_point_clouds_and_recordings_are_caught(tmp_path, previous):
    """Open3D's write_point_cloud returns True and rerun logs (not raises) when the disk fills: the file is cut
    short without a word. The writer checks what they wrote and publishes nothing."""
    import open3d as o3d

    from hsmap.io import atomic_path

    pts = np.random.default_rng(0).random((500, 3))
    for name, data in (("map.ply", None), ("slam.rrd", previous["slam.rrd"])):
        target = tmp_path / name
        target.write_bytes(previous[name])
        for keep in (0, 10, 0.5, -1):
            with pytest.raises(OutputError, match=f"{target}: incomplete"), atomic_path(target) as tmp:
                if data is None:
                    assert o3d.io.write_point_cloud(str(tmp), o3d.geometry.PointCloud(
                        o3d.utility.Vector3dVector(pts)))
                    whole = tmp.read_bytes()
                else:
                    whole = data
                cut = int(len(whole) * keep) if isinstance(keep, float) else keep % len(whole)
                tmp.write_bytes(whole[:cut])
            assert target.read_bytes() == previous[name] and hidden(tmp_path) == []


# --- disk full during each output of hsmap slam, segment and simulate ---------------------------------------------


def test_slam_disk_full_at_each_output_keeps_the_previous_run(bag, previous, tmp_path, monkeypatch, capsys):
    failed = []
    for k in range(1, 12):
        out = lay(previous, tmp_path / f"k{k}")
        with monkeypatch.context() as m:
            fsync = FsyncFails(m, k)
            rc = slam(bag, out)
        err = capsys.readouterr().err
        if rc == 0:  # every output written: the fault came after the last one
            assert k > len(SLAM_OUTPUTS) and sorted(snapshot(out)) == SLAM_OUTPUTS
            break
        assert rc == 2
        line = one_error_line(err)
        hit = [n for n in SLAM_OUTPUTS if line.startswith(f"hsmap: error: {out / n}: cannot write it (No space left")]
        assert len(hit) == 1 and Path(str(fsync.files[-1])).name.startswith(f".{hit[0]}."), (line, fsync.files)
        assert snapshot(out) == previous and hidden(out) == []
        failed.append(hit[0])
    assert sorted(failed) == SLAM_OUTPUTS  # each output in turn


def test_segment_disk_full_at_each_output_keeps_the_previous_run(tmp_path, monkeypatch, capsys):
    from PIL import Image

    img = np.zeros((80, 120), np.uint8)
    img[5:75, 5:55] = img[5:75, 65:115] = img[35:45, 55:65] = 254
    Image.fromarray(img).save(tmp_path / "map.png")
    first = tmp_path / "first"
    assert main(["segment", str(tmp_path / "map.png"), "--out", str(first)]) == 0
    capsys.readouterr()
    before = snapshot(first)
    for k in range(1, 12):
        out = lay(before, tmp_path / f"k{k}")
        with monkeypatch.context() as m:
            FsyncFails(m, k)
            rc = main(["segment", str(tmp_path / "map.png"), "--out", str(out)])
        err = capsys.readouterr().err
        if rc == 0:
            assert k > len(before)
            break
        assert rc == 2 and "No space left on device" in one_error_line(err)
        assert snapshot(out) == before and hidden(out) == []
    else:
        pytest.fail("segment never completed")


def test_simulate_disk_full_leaves_no_complete_looking_dataset(tmp_path, monkeypatch, capsys):
    """A failed simulation into a new folder leaves none of it (the folder it created is removed when nothing was
    published), or, failing while its files move in, a folder that reads as incomplete: dataset.yaml moves in
    last. No temporaries either way."""
    from hsmap.datasets.simulated import SimulatedDataset
    from hsmap.errors import DatasetError

    args = ["simulate", "two-rooms", "--max-frames", "2", "--out"]
    for k in (1, 4, 7):
        out = tmp_path / f"k{k}"
        with monkeypatch.context() as m:
            FsyncFails(m, k)
            rc = main([*args, str(out)])
        assert rc == 2 and "No space left on device" in one_error_line(capsys.readouterr().err)
        assert not (out / "dataset.yaml").exists()
        if out.exists():
            assert hidden(out) == []
            with pytest.raises(DatasetError, match="incomplete simulated dataset"):
                SimulatedDataset(out)


def _mount_tmpfs(where: Path, size_kb: int) -> None:
    where.mkdir(parents=True, exist_ok=True)
    if shutil.which("mount") is None:
        pytest.skip("no mount command: the small-filesystem test needs one")
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_kb}k", "tmpfs", str(where)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs here ({r.stderr.strip() or r.returncode}): needs root or "
                    "CAP_SYS_ADMIN; the fsync-injection tests cover the same paths")


def _fill(mnt: Path, free_kb: int, files: dict[str, bytes]) -> Path:
    """Empty the small filesystem, lay ``files`` in its folder ``out``, then fill it to ``free_kb`` KB free."""
    for p in mnt.iterdir():
        shutil.rmtree(p) if p.is_dir() else p.unlink()
    out = lay(files, mnt / "out")
    st = os.statvfs(mnt)
    size = st.f_bavail * st.f_frsize - free_kb * 1024
    if size > 0:
        with open(mnt / "filler", "wb") as fh:
            fh.write(b"\0" * size)
    return out


def _open_under(folder: Path) -> list[str]:
    """The files under ``folder`` this process holds open."""
    held = []
    for fd in os.listdir("/proc/self/fd"):
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
        if target.startswith(f"{folder}/"):
            held.append(target)
    return held


def test_slam_on_a_real_small_filesystem(bag, previous, tmp_path, capfd):
    """On a real 1 MiB tmpfs filled to 4 KB free and up (8 KB steps, with and without the recording: each step
    runs out in a different output, or half-way through one), ``hsmap slam`` either completes with every output
    whole, or ends with one line and the previous run untouched: never a truncated map.ply under its final name,
    never a hang (rerun's own file writer can hang on a full disk), never a temporary left, no file left open
    (Open3D's PLY writer leaves one, holding its space, and prints "RPly: Error closing up"), and nothing printed
    but that line."""
    import open3d as o3d

    from hsmap.io import verify_output

    mnt = tmp_path / "small"
    _mount_tmpfs(mnt, 1024)
    try:
        for extra, names in (([], SLAM_OUTPUTS), (["--no-recording"], [n for n in SLAM_OUTPUTS if n != "slam.rrd"])):
            kept = {n: previous[n] for n in names}
            failed_in, free_kb = set(), 4
            while True:
                out = _fill(mnt, free_kb, kept)
                rc = slam(bag, out, "--seed", "3", *extra)
                err = capfd.readouterr().err  # what Open3D and rerun print on the process's stderr included
                assert hidden(out) == [], (free_kb, extra)
                if rc == 0:
                    files = snapshot(out)
                    assert sorted(files) == names
                    n = json.loads(files["metrics.json"])["map_points"]
                    assert len(o3d.io.read_point_cloud(str(out / "map.ply")).points) == n
                    if "slam.rrd" in names:
                        verify_output(out / "slam.rrd")
                    break
                line = one_error_line(err)
                assert rc == 2 and "No space left on device" in line, (free_kb, extra, line)
                failed_in.add(re.match(rf"hsmap: error: {re.escape(str(out))}/([^:]+):", line).group(1))
                assert snapshot(out) == kept, (free_kb, extra)
                free_kb += 8
                assert free_kb < 1000, "never completed"
            assert "map.ply" in failed_in and len(failed_in) >= 2, failed_in
        assert _open_under(mnt) == []
    finally:
        if subprocess.run(["umount", str(mnt)], capture_output=True).returncode != 0:
            subprocess.run(["umount", "--lazy", str(mnt)], capture_output=True)  # never leave it mounted


def test_a_recording_cut_short_by_the_disk_ends_the_run_with_one_line(bag, previous, tmp_path, monkeypatch,
                                                                        capsys):
    """The recording's bytes reach the file through a thread of hsmap's, whose first failed write ends the run on
    one line, wherever the disk fills (at once, after one byte, a block, 32 KB, or in the last write, the
    footer's); rerun's own file writer, on a full disk, only logs the failure and can leave the flush that waits
    for it (and the interpreter's exit) hanging."""
    from hsmap.viz import rerun_core as hrr

    if not hrr._FileFeed.available():
        pytest.skip("the recording is written by rerun's own file writer on this platform")
    for budget in (0, 1, 4096, 32768, "footer"):  # a recording of this run: about 75 KB
        out = lay(previous, tmp_path / f"b{budget}")

        def put(self, data, budget=budget):
            done = getattr(self, "done", 0)
            room = max(budget - done, 0) if budget != "footer" else len(data) - (b"RRF2FOOT" in data)
            os.write(self._out, data[:room])
            self.done = done + min(room, len(data))
            if room < len(data):
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        monkeypatch.setattr(hrr._FileFeed, "_put", put)
        assert slam(bag, out, "--seed", "3") == 2
        assert one_error_line(capsys.readouterr().err) == (
            f"hsmap: error: {out / 'slam.rrd'}: cannot write it (No space left on device)")
        assert snapshot(out) == previous and hidden(out) == []


def test_a_study_cache_fill_on_a_full_disk_publishes_nothing(bag, tmp_path, monkeypatch):
    """The study caches are filled by the same writer: a full disk at each file of a cached SLAM run (its four
    outputs, then cache.json, written last) leaves no folder and no temporary; the next call computes it."""
    from hsmap.study.runs import cached_slam

    cache = tmp_path / "cache"
    failed_in = []
    for k in range(1, 10):
        with monkeypatch.context() as m:
            FsyncFails(m, k)
            try:
                run = cached_slam(bag, seed=3, cache_dir=cache)
            except OutputError as exc:
                assert str(exc).endswith("cannot write it (No space left on device)"), exc
                failed_in.append(Path(str(exc).split(": cannot write it")[0]).name)
                assert [p.name for p in cache.iterdir()] == [".locks"]
                continue
        break
    assert sorted(failed_in) == ["cache.json", "config.yaml", "map.ply", "metrics.json", "trajectory.tum"]
    assert not run.cached and len(run.trajectory) == 12
    assert cached_slam(bag, seed=3, cache_dir=cache).cached


def test_a_read_only_or_file_output_is_refused_before_the_run(bag, tmp_path, capsys, monkeypatch):
    """Checked before the long work: a --out that is a file, or whose folder cannot be written (a read-only
    mount where one can be made, else a folder that refuses writes), is one line naming --out."""
    import hsmap.slam

    ran = []
    monkeypatch.setattr(hsmap.slam, "run_slam", lambda *a, **k: ran.append(1))
    afile = tmp_path / "afile"
    afile.write_text("x")
    assert slam(bag, afile) == 2
    assert one_error_line(capsys.readouterr().err) == f"hsmap: error: --out {afile}: exists and is not a folder"
    ro = tmp_path / "ro"
    ro.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(ro)], capture_output=True)
    try:
        if r.returncode != 0:
            real_mkstemp = __import__("tempfile").mkstemp

            def refuse(*a, dir=None, **k):
                if dir is not None and Path(dir) == ro:
                    raise OSError(errno.EROFS, os.strerror(errno.EROFS))
                return real_mkstemp(*a, dir=dir, **k)

            monkeypatch.setattr("tempfile.mkstemp", refuse)
        assert slam(bag, ro / "out") == 2
        assert one_error_line(capsys.readouterr().err) == (
            f"hsmap: error: --out {ro / 'out'}: cannot create the folder in {ro} (Read-only file system)")
    finally:
        if r.returncode == 0:
            subprocess.run(["umount", str(ro)], capture_output=True)
    assert ran == []


# --- signals during hsmap slam -------------------------------------------------------------------------------------


@pytest.mark.parametrize("where", ["frame", "writing"])
@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_slam_interrupted_keeps_the_previous_run(bag, previous, tmp_path, monkeypatch, capsys, sig, code, where):
    """Ctrl-C (or SIGTERM) half-way through the frames, or while the outputs are written (the recording, the
    trajectory, the map and the configuration done, metrics.json next): one line, exit 130 (143), nothing
    published, no temporary left (the recording's included)."""
    import hsmap.slam

    # Python's own Ctrl-C handler, whatever an earlier test in this worker process left (a CI run on 5839747 had
    # SIGINT ignored in one xdist worker by the time this ran, so the run finished with 0)
    handler = signal.getsignal(signal.SIGINT)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    out = lay(previous, tmp_path / "out")
    if where == "frame":
        real = hsmap.slam.HsSlam.process

        def process(self, frame):
            if frame.index == 6:
                os.kill(os.getpid(), sig)  # delivered to this (main) thread before the next bytecode
            return real(self, frame)

        monkeypatch.setattr(hsmap.slam.HsSlam, "process", process)
    else:
        real_json = hsmap.slam.run.write_json

        def write_json(path, *a, **k):
            if Path(path).name == "metrics.json":
                assert sorted(p.name for p in Path(path).parent.iterdir() if not p.name.startswith(".")) == [
                    "config.yaml", "map.ply", "slam.rrd", "trajectory.tum"]
                os.kill(os.getpid(), sig)
            return real_json(path, *a, **k)

        monkeypatch.setattr(hsmap.slam.run, "write_json", write_json)
    try:
        assert slam(bag, out) == code
    finally:
        signal.signal(signal.SIGINT, handler)
    assert capsys.readouterr().err == "hsmap: interrupted\n"
    assert snapshot(out) == previous and hidden(out) == []


def _run(cmd: list[str], *, code: str | None = None, pre: list[str] = (), **kw) -> subprocess.Popen:
    """``hsmap CMD`` in a new process group (``code``: a script run instead of ``-m hsmap.cli``, given
    ``pre`` and then ``cmd`` as its arguments)."""
    env = dict(os.environ, RERUN_ANALYTICS="0", PYTHONUNBUFFERED="1")
    head = ["-c", code, *pre] if code is not None else ["-m", "hsmap.cli"]
    return subprocess.Popen([sys.executable, *head, *cmd], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env, process_group=0,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL), **kw)


def _wait_for(predicate, proc: subprocess.Popen, what: str, limit: float = 300.0) -> None:
    t0 = time.monotonic()
    while not predicate():
        if proc.poll() is not None:
            pytest.fail(f"the run ended (exit {proc.returncode}) before {what}: {proc.stderr.read()}")
        if time.monotonic() - t0 > limit:
            proc.kill()
            pytest.fail(f"never saw {what}")
        time.sleep(0.05)


_STOPPING_SLAM = """
import os, sys, time
from pathlib import Path

import hsmap.slam
from hsmap.cli import main

marker, where = sys.argv[1], sys.argv[2]


def stop():  # say so, then wait for the test's signal, handled at the next short sleep's end whichever thread
    # caught it and whenever it came
    Path(marker).write_text(str(os.getpid()))
    while True:
        time.sleep(0.05)


if where == "frame":
    process = hsmap.slam.HsSlam.process
    hsmap.slam.HsSlam.process = lambda self, frame: stop() if frame.index == 6 else process(self, frame)
else:
    write_json = hsmap.slam.run.write_json
    hsmap.slam.run.write_json = lambda path, *a, **k: (
        stop() if Path(path).name == "metrics.json" else write_json(path, *a, **k))
sys.exit(main(sys.argv[3:]))
"""


@pytest.mark.parametrize("where, sig", [("frame", signal.SIGKILL), ("writing", signal.SIGKILL),
                                        ("writing", signal.SIGINT)])
def test_slam_process_killed_or_interrupted(bag, previous, tmp_path, capsys, where, sig):
    """A real ``hsmap slam`` process, stopped half-way through the frames or while writing its outputs (all but
    metrics.json done), then killed (SIGKILL) or interrupted (SIGINT to its process group, as a terminal's
    Ctrl-C). Killed: the previous run is intact, the killed run's staging folder (with its .tmp.rrd, or its
    finished-looking files) is hidden and left, and the next run into the folder removes it. Interrupted: one
    line, exit 130, the previous run intact, nothing left."""
    out = lay(previous, tmp_path / "out")
    marker = tmp_path / "marker"
    proc = _run(["slam", str(bag), "--out", str(out), "--quiet"], code=_STOPPING_SLAM, pre=[str(marker), where])
    _wait_for(marker.exists, proc, f"the run stopped at {where}")
    stage = [p for p in out.iterdir() if p.name.startswith(".hsmap-staging-")]
    assert len(stage) == 1
    staged = sorted(p.name for p in stage[0].iterdir())
    if where == "frame":
        assert len(staged) == 1 and staged[0].startswith(".slam.rrd.") and staged[0].endswith(".tmp.rrd")
    else:
        assert staged == ["config.yaml", "map.ply", "slam.rrd", "trajectory.tum"]
    os.killpg(proc.pid, sig)
    try:
        _, err = proc.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        pytest.fail(f"the run did not end within 120 s of signal {sig!r}")
    if sig == signal.SIGKILL:
        assert proc.returncode == -signal.SIGKILL
        left = snapshot(out)
        assert {k: v for k, v in left.items() if not k.startswith(".")} == previous and hidden(out)
        assert slam(bag, out, "--max-frames", "4") == 0
        capsys.readouterr()
        assert hidden(out) == [] and sorted(snapshot(out)) == SLAM_OUTPUTS
    else:
        assert (proc.returncode, err) == (130, "hsmap: interrupted\n")
        assert snapshot(out) == previous and hidden(out) == []


# --- hsmap reproduce: interrupts, kills, two batches at once --------------------------------------------------------


def _notebook(path: Path) -> None:
    """A study notebook that can be told to wait for a gate file, to fail, and to say it is running."""
    import nbformat

    nb = nbformat.v4.new_notebook()
    params = nbformat.v4.new_code_cell('quick: bool = False\nout_dir: str = "."\ngate: str = ""\nfail: bool = False\n'
                                       'marker: str = ""')
    params.metadata["tags"] = ["parameters"]
    body = nbformat.v4.new_code_cell(
        "import json, os, pathlib, time\n"
        "folder = pathlib.Path(out_dir) / os.environ['HSMAP_NOTEBOOK']\n"
        "folder.mkdir(parents=True, exist_ok=True)\n"
        "if marker:\n"
        "    pathlib.Path(marker).write_text(str(os.getpid()))\n"
        "t0 = time.monotonic()\n"
        "while gate and not pathlib.Path(gate).exists() and time.monotonic() - t0 < 600:\n"
        "    time.sleep(0.05)\n"
        "if fail:\n"
        "    raise RuntimeError('asked to fail')\n"
        "(folder / 'metrics.json').write_text(json.dumps({'notebook': folder.name, 'metrics': {'x': 1}}))\n")
    nb.cells = [nbformat.v4.new_markdown_cell(f"# {path.stem}"), params, body]
    nbformat.write(nb, str(path))


def _reports(out: Path, names=("01-wait", "02-quick")) -> dict[str, bytes]:
    files = snapshot(out)
    return {k: v for k, v in files.items() if k.split("/")[0].split(".")[0] in names}


def _index(out: Path) -> dict[str, dict]:
    return {e["name"]: e for e in json.loads((out / "index.json").read_text())["notebooks"]}


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def test_a_batch_finishing_later_keeps_the_entries_another_wrote_meanwhile(tmp_path, monkeypatch):
    """Batch A runs 01 (long); meanwhile batch B runs 02, which fails, and writes its entry; A finishes last. A's
    index keeps B's entry, not its own stale copy of 02's earlier "ok"."""
    import hsmap.study.batch as batch
    import hsmap.study.notebook_run as notebook_run
    from hsmap.io import folder_lock, write_json

    nbdir, out = tmp_path / "notebooks", tmp_path / "reports"
    nbdir.mkdir()
    _notebook(nbdir / "01-wait.ipynb")
    _notebook(nbdir / "02-quick.ipynb")
    spec = {s.name: s for s in batch.discover(nbdir)}
    earlier = notebook_run.NotebookRun(name="02-quick", notebook=str(spec["02-quick"].path), status="ok",
                                started="2026-01-01T00:00:00+00:00", duration_s=1.0)
    write_json(out / "02-quick" / "run.json", earlier.to_dict())  # what A sees of 02 when it starts

    def a_runs_01_while_b_runs_02(s, *args):
        failed = notebook_run.NotebookRun(name="02-quick", notebook=str(spec["02-quick"].path), status="failed",
                                   error="RuntimeError: asked to fail", started=notebook_run.now_text(), duration_s=0.5)
        with folder_lock(out):  # what batch B publishes meanwhile, as it does: run.json, then its index
            write_json(out / "02-quick" / "run.json", failed.to_dict())
            write_json(out / "index.json", {"notebooks": [failed.to_dict()]})
        return notebook_run.NotebookRun(name=s.name, notebook=str(s.path), status="ok", started=notebook_run.now_text(),
                                 duration_s=2.0).to_dict()

    monkeypatch.setattr(batch, "_worker", a_runs_01_while_b_runs_02)
    result = batch.run_notebooks(nbdir, out, only=["01"], log=None)
    assert {e.name: e.status for e in result.entries} == {"01-wait": "ok", "02-quick": "failed"}
    assert [e["status"] for e in json.loads((out / "index.json").read_text())["notebooks"]] == ["ok", "failed"]


def test_reproduce_disk_full_at_each_output_keeps_the_previous_report(tmp_path, monkeypatch, capsys):
    """A full disk at each file ``hsmap reproduce`` writes in turn: the index (HTML and JSON, rewritten as the
    batch goes) and the notebook's report (executed notebook, HTML, run.json). A failed index is one line, exit
    2; a report that cannot be written fails that notebook (exit 1, its index entry says why, naming the report,
    not its staging copy). Either way the previous report is intact and no temporary is left. The kernel is
    replaced by a stand-in that writes what a notebook writes (papermill's output notebook, metrics.json)."""
    import nbformat
    import papermill

    nbdir, out = tmp_path / "notebooks", tmp_path / "reports"
    nbdir.mkdir()
    _notebook(nbdir / "01-wait.ipynb")

    def execute_notebook(input_path, output_path, parameters=None, **kw):
        folder = Path(parameters["out_dir"]) / os.environ["HSMAP_NOTEBOOK"]
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "metrics.json").write_text(json.dumps({"notebook": folder.name, "metrics": {"x": 1}}))
        nb = nbformat.read(input_path, as_version=4)
        nbformat.write(nb, output_path)
        return nb

    monkeypatch.setattr(papermill, "execute_notebook", execute_notebook)
    args = ["reproduce", "--notebooks", str(nbdir), "--out", str(out), "--only", "01"]
    assert main(args) == 0
    capsys.readouterr()
    report = _reports(out)
    assert sorted(report) == ["01-wait.html", "01-wait.ipynb", "01-wait/metrics.json", "01-wait/run.json"]
    failed_in = set()
    for k in range(1, 30):
        with monkeypatch.context() as m:
            FsyncFails(m, k)
            rc = main(args)
        so, err = capsys.readouterr()
        if rc == 0:
            break
        assert hidden(out) == [], k
        now = _reports(out)
        if now != report:  # published whole before an index write failed: a complete new report
            assert rc == 2 and sorted(now) == sorted(report) and now["01-wait/metrics.json"] == report[
                "01-wait/metrics.json"]
            assert json.loads(now["01-wait/run.json"])["status"] == "ok", k
            report = now
        if rc == 2:
            line = one_error_line(err)
            name = re.fullmatch(rf"hsmap: error: {re.escape(str(out))}/(index\.html|index\.json): cannot write it "
                                r"\(No space left on device\)", line)
            assert name, line
            failed_in.add(name.group(1))
        else:
            assert rc == 1 and err == "failed: 01-wait\n"
            entry = _index(out)["01-wait"]
            name = re.fullmatch(rf"hsmap reproduce: OutputError: {re.escape(str(out))}/(01-wait\.ipynb|01-wait\.html|"
                                r"01-wait/run\.json): cannot write it \(No space left on device\)", entry["error"])
            assert entry["status"] == "failed" and name, entry
            failed_in.add(name.group(1))
    else:
        pytest.fail("the batch never completed")
    assert failed_in == {"index.html", "index.json", "01-wait.ipynb", "01-wait.html", "01-wait/run.json"}
    assert _index(out)["01-wait"]["status"] == "ok"


@pytest.mark.slow
def test_reproduce_under_concurrency_interrupts_and_kills(tmp_path, capfd):
    """Two batches at once, interrupts and kills, on two small notebooks, with real processes and signals:

    0. a run where nothing fails is quiet (the kernels are shut down without a SIGINT, which makes them log
       "[IPKernelApp] ERROR | KeyboardInterrupt caught in kernel.", and their stderr is the report's);
    1. two batches at once (A waiting in 01 while B runs 02, which fails) keep each other's entries;
    2. SIGKILL of batch A: 01's previous report is intact, its staging folder is left, and the next batch removes
       it and lists 01 with its previous result;
    3. Ctrl-C (SIGINT to the process group, as a terminal sends it) of a batch running both on two workers:
       one line, exit 130, both previous reports intact, no temporary left, no kernel left running.
    """
    from hsmap.study.batch import run_notebooks

    nbdir, out = tmp_path / "notebooks", tmp_path / "reports"
    nbdir.mkdir()
    _notebook(nbdir / "01-wait.ipynb")
    _notebook(nbdir / "02-quick.ipynb")
    first = run_notebooks(nbdir, out, log=None)
    assert first.ok and capfd.readouterr().err == ""
    before = _reports(out)

    # 1. batch A runs 01 and waits in it; batch B runs 02, which fails, and ends
    gate, marker = tmp_path / "gate", tmp_path / "marker-a"
    a = _run(["reproduce", "--notebooks", str(nbdir), "--out", str(out), "--only", "01", "-p", "gate", str(gate),
              "-p", "marker", str(marker)])
    _wait_for(marker.exists, a, "batch A inside notebook 01")
    b = run_notebooks(nbdir, out, only=["02"], parameters={"fail": True}, log=None)
    assert [r.status for r in b.runs] == ["failed"]
    index = _index(out)
    assert index["01-wait"]["status"] == "running" and index["02-quick"]["status"] == "failed"
    assert json.loads((out / "02-quick" / "run.json").read_text())["status"] == "failed"

    # 2. SIGKILL batch A inside notebook 01
    os.killpg(a.pid, signal.SIGKILL)
    a.communicate()
    assert {k: v for k, v in _reports(out).items() if k.startswith("01")} == {
        k: v for k, v in before.items() if k.startswith("01")}
    assert [h for h in hidden(out) if "hsmap-staging-01-wait" in h]  # the killed run's leftovers...
    again = run_notebooks(nbdir, out, only=["02"], log=None)
    assert hidden(out) == []  # ... removed by the next batch
    assert {e.name: e.status for e in again.entries} == {"01-wait": "ok", "02-quick": "ok"}
    before = _reports(out)

    # 3. Ctrl-C while both notebooks run, on two workers
    markers = [tmp_path / "m1", tmp_path / "m2"]
    c = _run(["reproduce", "--notebooks", str(nbdir), "--out", str(out), "--jobs", "2", "-p", "gate", str(gate),
              "--parameters-file", str(_params(tmp_path, markers))])
    _wait_for(lambda: all(m.exists() for m in markers), c, "both notebooks running")
    kernels = [int(m.read_text()) for m in markers]
    os.killpg(c.pid, signal.SIGINT)
    so, se = c.communicate(timeout=300)
    assert c.returncode == 130 and se == "hsmap: interrupted\n", se
    assert _reports(out) == before and hidden(out) == []
    t0 = time.monotonic()
    while any(_alive(p) for p in kernels) and time.monotonic() - t0 < 60:
        time.sleep(0.1)
    assert not any(_alive(p) for p in kernels)
    index = _index(out)
    assert [index[n]["status"] for n in ("01-wait", "02-quick")] == ["ok", "ok"]
    assert all("was interrupted; this is the previous run" in index[n]["warnings"][-1]
               for n in ("01-wait", "02-quick"))


def test_an_interrupted_batch_drops_the_notebook_machinerys_last_words(caplog):
    """Ctrl-C shuts the kernel down under a cell that still waits for its reply: nbclient then logs "Kernel
    died while waiting for execute reply." and asyncio "Task exception was never retrieved" (a race that the
    test above lost once in CI). Once the batch is interrupted, the machinery's loggers say nothing; before,
    they are heard."""
    import logging

    from hsmap.study import interrupts

    interrupts.quiet_papermill_log()
    outer = signal.signal(signal.SIGINT, signal.default_int_handler)  # as in a terminal (pytest-xdist ignores it)
    try:
        with pytest.raises(KeyboardInterrupt):
            with interrupts.marking_interrupts():
                logging.getLogger("papermill").error("a cell failed")
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(5)  # the signal arrives before this ends
        logging.getLogger("papermill").error("Kernel died while waiting for execute reply.")
        logging.getLogger("asyncio").error("Task exception was never retrieved")
        assert caplog.messages == ["a cell failed"]
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # the terminal's Ctrl-C is back
        # a process that ignores Ctrl-C (a batch worker) keeps ignoring it
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        with interrupts.marking_interrupts():
            assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, outer)
        interrupts._interrupted = False


def _params(folder: Path, markers: list[Path]) -> Path:
    p = folder / "params.yaml"
    p.write_text(json.dumps({"notebooks": {"01": {"marker": str(markers[0])}, "02": {"marker": str(markers[1])}}}))
    return p
