"""hsmap._blas: importing hsmap leaves the host's BLAS threads and environment alone; the hot loops run on
$HSMAP_BLAS_THREADS threads and give the host's setting back."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from threadpoolctl import threadpool_info

import hsmap._blas as blas
from hsmap.errors import ConfigError

PROBE = """
import json, os
import threadpoolctl, numpy, scipy.linalg
def blas():
    return sorted(i["num_threads"] for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas")
env = dict(os.environ)
before = blas()
import hsmap
after_import = blas()
import hsmap._blas as b
with b.limited_blas():
    inside = blas()
from hsmap.testing import raycast_2d, office_segments, scan_points_2d
pts = scan_points_2d(*raycast_2d(office_segments(), [2.0, 2.0, 0.0], rng=0))
hsmap.harmony_icp(pts, pts, rng=0)
print(json.dumps({"before": before, "after_import": after_import, "inside": inside, "after_call": blas(),
                  "env_changed": sorted(k for k in os.environ if os.environ.get(k) != env.get(k))}))
"""


def _probe(**env):
    full = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                                                             "OMP_NUM_THREADS", "HSMAP_BLAS_THREADS")}
    p = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, env={**full, **env},
                       timeout=300)
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout.strip().splitlines()[-1])


def test_importing_hsmap_changes_nothing_and_the_hot_loops_give_the_limit_back():
    r = _probe(OPENBLAS_NUM_THREADS="2")  # the host's own choice, whatever the machine has
    assert r["before"] and set(r["before"]) == {2}
    assert r["after_import"] == r["before"] and r["after_call"] == r["before"]
    assert set(r["inside"]) == {1}
    assert r["env_changed"] == []  # no OPENBLAS_NUM_THREADS, no RERUN_ANALYTICS set behind the caller's back


def test_the_limit_follows_hsmap_blas_threads():
    r = _probe(OPENBLAS_NUM_THREADS="2", HSMAP_BLAS_THREADS="2")
    assert set(r["inside"]) == {2}


def test_nested_limits_share_one_and_restore_the_host_setting(monkeypatch):
    host = sorted(i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas")
    monkeypatch.setenv(blas.BLAS_THREADS_ENV, "1")
    with blas.limited_blas():
        with blas.limited_blas():
            assert {i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"} == {1}
        assert {i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"} == {1}  # outer still on
    assert sorted(i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas") == host

    @blas.blas_limited
    def product(a):
        return a @ a.T

    np.testing.assert_allclose(product(np.eye(3)), np.eye(3))
    assert product.__name__ == "product"


@pytest.mark.parametrize("value", ["0", "-2", "many"])
def test_a_bad_thread_count_names_the_variable(monkeypatch, value):
    monkeypatch.setenv(blas.BLAS_THREADS_ENV, value)
    with pytest.raises(ConfigError, match="HSMAP_BLAS_THREADS"):
        blas.blas_threads()
