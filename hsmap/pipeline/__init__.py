"""The paper's chain on one recording, as ``hsmap map`` runs it: the stage cache (:mod:`~hsmap.pipeline.cache`),
cached HS-SLAM runs (:mod:`~hsmap.pipeline.runs`), the settings of the whole chain (:mod:`~hsmap.pipeline.config`)
and the chain itself (:mod:`~hsmap.pipeline.chain`; with a 3D LiDAR only, :mod:`~hsmap.pipeline.chain3d`). Used by the command, the notebooks and the benchmarks; it
knows nothing of the repository's folders (every path is an argument)."""

from .cache import FolderCache, code_digest, description_digest
from .chain import OUTPUTS, STAGES, map_recording
from .chain3d import given_poses, map_recording_3d
from .config import ChainConfig, GridsConfig, load_chain_config
from .runs import SlamRun, cached_slam, dataset_fingerprint, slam_key

__all__ = ["FolderCache", "code_digest", "description_digest", "map_recording", "map_recording_3d", "given_poses", "STAGES", "OUTPUTS", "ChainConfig",
           "GridsConfig", "load_chain_config", "SlamRun", "cached_slam", "dataset_fingerprint", "slam_key"]
