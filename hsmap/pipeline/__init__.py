"""The paper's chain on one recording, as ``hsmap map`` runs it: the stage cache (:mod:`~hsmap.pipeline.cache`),
cached HS-SLAM runs (:mod:`~hsmap.pipeline.runs`), the settings of the whole chain (:mod:`~hsmap.pipeline.config`)
and the chain itself (:mod:`~hsmap.pipeline.chain`). Used by the command, the notebooks and the benchmarks; it
knows nothing of the repository's folders (every path is an argument)."""

from .cache import FolderCache, code_digest, description_digest
from .chain import OUTPUTS, STAGES, map_recording
from .config import ChainConfig, GridsConfig, load_chain_config
from .runs import SlamRun, cached_slam, dataset_fingerprint, slam_key

__all__ = ["FolderCache", "code_digest", "description_digest", "map_recording", "STAGES", "OUTPUTS", "ChainConfig",
           "GridsConfig", "load_chain_config", "SlamRun", "cached_slam", "dataset_fingerprint", "slam_key"]
