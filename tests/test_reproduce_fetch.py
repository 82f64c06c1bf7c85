"""``hsmap reproduce`` downloads the public data it lacks before running the notebooks (fetch_missing)."""

from __future__ import annotations

import pytest

from hsmap.commands.reproduce import fetch_missing
from hsmap.errors import DatasetError
from hsmap.study.public_data import dataset_folder, registry


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """An empty user cache and no $HSMAP_DATASETS: the datasets folder is the download folder."""
    import hsmap.study.paths as paths

    monkeypatch.delenv("HSMAP_DATASETS", raising=False)
    monkeypatch.setenv("HSMAP_CACHE", str(tmp_path / "cache"))
    dest = tmp_path / "cache" / "datasets"
    monkeypatch.setattr(paths, "datasets_dir", lambda: dest)
    return dest


def _fake_fetch(calls, fail=()):
    def fetch(names, *, dest, log):
        for name in names:
            calls.append(name)
            if name in fail:
                raise DatasetError(f"{name}: download failed: URLError: no network")
            ds = registry()[name]
            for f in ds.files:
                p = dest / ds.folder / f.path
                p.parent.mkdir(parents=True, exist_ok=True)
                p.write_bytes(b"x")
        return []
    return fetch


def test_fetches_what_is_missing_and_only_that(cache):
    calls: list[str] = []
    lines: list[str] = []
    status = fetch_missing(lines.append, fetch=_fake_fetch(calls))
    assert sorted(calls) == sorted(registry()) and set(status.values()) == {"fetched"}
    assert all(dataset_folder(n, cache) is not None for n in registry())
    calls.clear()
    status = fetch_missing(lines.append, fetch=_fake_fetch(calls))
    assert calls == [] and set(status.values()) == {"present"}


def test_no_network_goes_on_and_says_why(cache):
    calls: list[str] = []
    lines: list[str] = []
    first = next(iter(registry()))
    status = fetch_missing(lines.append, fetch=_fake_fetch(calls, fail={first}))
    assert status[first].startswith("failed: ") and "no network" in status[first]
    assert all(v == "fetched" for k, v in status.items() if k != first)
    assert any(first in line and "skip" in line for line in lines)


def test_nothing_is_downloaded_into_hsmap_datasets(tmp_path, monkeypatch):
    monkeypatch.setenv("HSMAP_DATASETS", str(tmp_path / "mine"))
    calls: list[str] = []
    lines: list[str] = []
    status = fetch_missing(lines.append, fetch=_fake_fetch(calls))
    assert calls == [] and all(v.startswith("missing: ") for v in status.values())
    assert len(lines) == len(registry())
