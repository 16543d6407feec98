"""Training, checkpoints and export of the networks in :mod:`posecast.offline.nets` (torch)."""
