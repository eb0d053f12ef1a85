"""fgins: GNSS/INS factor-graph smoothing (GTSAM) with Kalman-filter baselines."""

__version__ = "0.1.0"
