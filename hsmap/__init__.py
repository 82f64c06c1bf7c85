"""hsmap: multi-LiDAR indoor mapping with Harmony Search."""
__version__ = "0.1.0"
