"""The real-time engine: batched decoding, FK, contact IK, anomaly scoring and SSI (no I/O)."""
