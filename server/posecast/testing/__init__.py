"""Helpers for tests and benchmarks of posecast: a real ``posecast serve`` subprocess
(:mod:`~posecast.testing.serve`) and a lossy, jittery WebSocket relay to put between
it and its clients (:mod:`~posecast.testing.relay`)."""
