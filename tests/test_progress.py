"""Progress lines (hsmap.progress): a line when a stage starts, a heartbeat after ``interval`` seconds without a
line saying what is done and how far, nothing at all unless a caller reports, and progress bars that count."""

from __future__ import annotations

import threading
import time

import pytest

from hsmap import progress


class FakeClock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def clock():
    return FakeClock()


def test_a_stage_start_is_a_line_at_once(clock):
    lines = []
    hb = progress.Heartbeat(lines.append, interval=60, clock=clock)
    hb.stage("slam3d", "6-DOF HS-SLAM on 1777 clouds")
    assert lines == ["slam3d: started, 6-DOF HS-SLAM on 1777 clouds"]


def test_a_stage_not_announced_is_named_by_the_heartbeat_only(clock):
    lines = []
    hb = progress.Heartbeat(lines.append, interval=60, clock=clock)
    hb.stage("read", announce=False)
    assert lines == []
    clock.now += 60
    assert hb.tick() and lines == ["read: still running, 1 min 00 s (in all 1 min 00 s)"]


def test_the_heartbeat_comes_after_interval_seconds_without_a_line_and_says_how_far(clock):
    lines = []
    with progress.reporting(lines.append, interval=60, clock=clock, beat=False) as hb:
        hb.tick()
        progress.stage("slam3d")
        bar = progress.bar(1777, unit="cloud", desc="HS-SLAM 6-DOF", progress=False)
        bar.update(812)
        clock.now += 59.9
        assert not hb.tick()
        clock.now += 0.1
        assert hb.tick()
        assert lines[-1] == "slam3d: HS-SLAM 6-DOF: cloud 812/1777, 1 min 00 s (in all 1 min 00 s)"
        assert not hb.tick()  # the heartbeat was a line: the next is due a whole interval later
        clock.now += 30
        progress.say("a line of the work's own")
        clock.now += 45
        assert not hb.tick()
        clock.now += 15
        assert hb.tick()
        bar.close()
        clock.now += 60
        assert hb.tick()
        assert lines[-1] == "slam3d: still running, 3 min 30 s (in all 3 min 30 s)"
    assert lines[:2] == ["slam3d: started", lines[1]]
    assert len(lines) == 5


def test_a_callers_status_says_how_far(clock):
    lines = []
    running = ["03-hs-slam-6dof: cell 7/15"]
    with progress.reporting(lines.append, interval=60, clock=clock, beat=False) as hb, \
            progress.describing(lambda: "; ".join(running) + ", 4 of 10 notebooks done"):
        clock.now += 125
        hb.tick()
    assert lines == ["working: 03-hs-slam-6dof: cell 7/15, 4 of 10 notebooks done, 2 min 05 s"]


def test_a_status_that_fails_is_said_and_does_not_stop_the_run(clock):
    lines = []
    with progress.reporting(lines.append, interval=1, clock=clock, beat=False) as hb, progress.describing(lambda: 1 / 0):
        clock.now += 1
        assert hb.tick()
    assert "status unavailable: ZeroDivisionError" in lines[0]


def test_without_a_reporting_caller_the_library_says_nothing(capsys):
    progress.stage("slam2d")
    progress.say("nothing")
    bar = progress.bar(3, unit="scan", progress=False)
    bar.update(3)
    bar.close()
    assert bar.n == 3
    assert capsys.readouterr() == ("", "")


def test_the_heartbeat_thread_writes_lines_while_the_work_runs():
    lines = []
    seen = threading.Event()

    def log(line):
        lines.append(line)
        if len(lines) >= 3:
            seen.set()

    with progress.reporting(log, interval=0.05):
        progress.stage("grids")
        bar = progress.bar(10, unit="frame", desc="grids", progress=False)
        bar.update(4)
        assert seen.wait(10)
        bar.close()
    n = len(lines)
    time.sleep(0.2)
    assert len(lines) == n  # the thread ends with the block
    assert lines[0] == "grids: started" and lines[1].startswith("grids: grids: frame 4/10, ")


@pytest.mark.parametrize("seconds, text", [(0.4, "0 s"), (45, "45 s"), (185, "3 min 05 s"), (3725, "1 h 02 min")])
def test_format_seconds(seconds, text):
    assert progress.format_seconds(seconds) == text
