"""``posecast bench latency``: capture to display, measured with real SDK clients.

The data path, and the module for each part::

    sender (SDK, walk at 60 Hz, capture stamp) --> posecast serve (look-ahead, tick)
        --> receiver (SDK decode) --> interpolator --> 90 Hz display loop
    players.py: the client processes      display.py: when a pose is first shown
    node_players.py: the same, TypeScript SDK players in Node (--sdk typescript)
    budget.py:  the split of each pose's time      run.py: server, relay, phases

``display`` and ``budget`` are pure (times in, figures out); ``players`` and ``run``
are the shell. The method and the figures are in ``docs/latency-benchmark.md``.
"""
