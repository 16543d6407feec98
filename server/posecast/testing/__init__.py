"""Helpers for tests and benchmarks of posecast: a real ``posecast serve`` subprocess
(:mod:`~posecast.testing.serve`), a lossy, jittery WebSocket relay to put between it
and its clients (:mod:`~posecast.testing.relay`), and shown poses as the engine thread
makes them, for driving routing without an engine (:mod:`~posecast.testing.poses`)."""
