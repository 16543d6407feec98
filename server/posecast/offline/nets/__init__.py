"""The networks of the paper (Sec. 3.1, 3.2.1, 4.2): a GRU conditional VAE and an anomaly AE.

Model files do no I/O. Each network has a config dataclass; checkpoints and exported
sidecars carry that config, so a model is always rebuilt from its artifact.
"""
