"""``posecast eval``: the shipped models on held-out motion, measured as the paper's Table 1."""
