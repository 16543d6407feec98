"""The pure core of the server: sessions, admission, routing, rooms, outboxes, the
cluster sink and the tick inbox. Bytes and ``now`` in, outbox contents out; no I/O,
no clock, no inference library (tests/online/core/test_purity.py)."""
