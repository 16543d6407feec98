"""The engine tests' fixtures, for the inference tests that run every backend
(``test_anomaly.py``: each backend's candidate pool against the scorer)."""

from tests.online.engine.conftest import anomaly_artifact, backend, scorer, walk_arrays

__all__ = ["anomaly_artifact", "backend", "scorer", "walk_arrays"]
