"""Training, checkpoints and export for the networks in :mod:`posecast.model` (needs torch)."""
