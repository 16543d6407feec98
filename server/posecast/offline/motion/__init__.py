"""Motion data in: BVH files, rig maps, retargeting onto the canonical skeleton."""
