"""Helpers for tests and benchmarks of posecast: a real ``posecast serve`` subprocess."""
