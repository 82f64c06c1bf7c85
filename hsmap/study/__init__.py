"""The reproduction layer: everything the study notebooks, ``hsmap reproduce`` and the benchmark scripts chain
together, kept apart from the core library (which knows nothing of the repository, its ``data/`` or its
caches).

- :mod:`~hsmap.study.datasets`, :mod:`~hsmap.study.runs`, :mod:`~hsmap.study.maps`: simulated datasets, cached
  HS-SLAM runs, the maps made from them, kept by the one cache (:mod:`hsmap.pipeline.cache`) under ``data/``;
- :mod:`~hsmap.study.recording`: a cached run replayed into a rerun recording;
- :mod:`~hsmap.study.benchmarks`: the Freiburg and IPA benchmarks beside the published numbers
  (``hsmap/study/published.yaml``);
- :mod:`~hsmap.study.report`: what a notebook writes (:class:`NotebookReport`) and the batch's HTML index;
- :mod:`~hsmap.study.batch`: the notebooks run by papermill (``hsmap reproduce``);
- :mod:`~hsmap.study.public_data`: the public benchmark files, their sources and hashes, ``hsmap data fetch``;
- :mod:`~hsmap.study.paths`: where things are, in a checkout of the repository or an installed hsmap.

Notebooks use it as ``from hsmap import study as hs``.
"""

from .benchmarks import (
    BORMANN_BUILDINGS,
    FREIBURG_LOGS,
    FreiburgResults,
    freiburg_relations,
    open_freiburg,
    published_references,
    real_benchmark_metrics,
    room_segmentation_benchmark,
    segmentation_table,
    summarise_segmentation,
)
from .datasets import simulated_dataset
from .maps import (
    MapSegmentations,
    TwoLidarMaps,
    door_errors,
    map_distances,
    point_map,
    point_maps,
    recording_maps,
    scan_grid,
    segment_maps,
    true_room_names,
    two_lidar_maps,
)
from .paths import datasets_dir, generated_dir, notebooks_dir, reports_dir
from .public_data import dataset_folder, fetch, missing_data_reason
from .recording import (
    overlap_blueprint,
    record_overlap,
    record_slam_run,
    record_topology,
    slam_blueprint,
    topology_blueprint,
)
from .report import NotebookReport
from .runs import SimulatedRuns, SlamRun, cached_slam, dataset_fingerprint, simulated_slam_runs, slam_key

__all__ = [
    "BORMANN_BUILDINGS",
    "FREIBURG_LOGS",
    "FreiburgResults",
    "MapSegmentations",
    "NotebookReport",
    "SimulatedRuns",
    "SlamRun",
    "TwoLidarMaps",
    "cached_slam",
    "dataset_fingerprint",
    "dataset_folder",
    "datasets_dir",
    "door_errors",
    "fetch",
    "freiburg_relations",
    "generated_dir",
    "map_distances",
    "missing_data_reason",
    "notebooks_dir",
    "open_freiburg",
    "point_map",
    "point_maps",
    "published_references",
    "real_benchmark_metrics",
    "record_slam_run",
    "slam_blueprint",
    "record_overlap",
    "overlap_blueprint",
    "record_topology",
    "topology_blueprint",
    "recording_maps",
    "reports_dir",
    "room_segmentation_benchmark",
    "scan_grid",
    "segment_maps",
    "segmentation_table",
    "simulated_dataset",
    "simulated_slam_runs",
    "slam_key",
    "summarise_segmentation",
    "true_room_names",
    "two_lidar_maps",
]
