"""Benchmarks behind ``posecast bench`` (the scripts in ``benchmarks/`` call these)."""
