"""The online (serving) path, in data-path order: ``protocol`` (wire messages) ->
``auth`` (join tokens) -> ``core`` (pure session, admission, routing, rooms) ->
``engine`` (batched SSI) on ``inference`` (ONNX Runtime) -> ``shell`` (asyncio,
HTTP, logging), with ``cluster`` (the bus between nodes) beside the core.
``config`` and ``metrics`` are built once at the edge and handed to every layer."""
