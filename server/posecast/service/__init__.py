"""The pose-streaming service: sessions, rooms, the tick, and the WebSocket shell.

Data path: ``app`` (bytes) -> ``session`` (one connection's protocol state) ->
``hub`` (rooms, routing) -> ``ticker`` (one batched engine step per tick) ->
``outbox`` (latest-wins per client) -> ``app`` (bytes out).
"""
