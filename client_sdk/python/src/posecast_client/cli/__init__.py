"""Console scripts: ``posecast-sim`` and ``posecast-record``."""
