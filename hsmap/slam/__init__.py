"""HS-SLAM (the paper's Algorithm 3): scan-to-map Harmony-ICP in 2D (3-DOF) and 3D (6-DOF).

Each frame is registered (:mod:`~hsmap.slam.tracker`) with :func:`hsmap.harmony_icp` against a local map around the
robot, its search seeded by the previous pose, the last motion repeated, the odometry's prediction, the recent
poses' mean and, in 6-DOF, a 2D run's pose (:mod:`~hsmap.slam.prediction`). The registration is checked against
the motion prediction and fused with it (:mod:`~hsmap.slam.verify`); the odometry's bias and noise are learned as
the run goes (:mod:`~hsmap.slam.odometry`). Keyframes form a pose graph with tracking, wheel, scan-to-scan and loop
edges, optimised with GTSAM, and the tracking map is built from the keyframes near the newest one along the graph
(:mod:`~hsmap.slam.keyframes`). :func:`run_slam` runs a dataset, :func:`write_slam_outputs` writes its files
(:mod:`~hsmap.slam.run`); the settings are :class:`SlamConfig` (:mod:`~hsmap.slam.config`).
"""

from .config import KeyframeGraphConfig, SlamConfig
from .costs import Costs
from .frames import frame_points, grazing_where_sparse, sampled_as_its_normal_says
from .keyframes import KeyframeGraph
from .odometry import OdometryModel
from .prediction import MotionPrediction
from .run import SlamResult, prior_coverage, run_slam, write_slam_outputs
from .tracker import FrameResult, HsSlam
from .verify import Verifier

__all__ = ["SlamConfig", "Costs", "KeyframeGraphConfig", "FrameResult", "SlamResult", "HsSlam", "run_slam",
           "write_slam_outputs", "frame_points", "prior_coverage", "grazing_where_sparse",
           "sampled_as_its_normal_says", "OdometryModel", "MotionPrediction", "Verifier", "KeyframeGraph"]
