"""Rotation conversions and forward kinematics (numpy; torch twins for training)."""
