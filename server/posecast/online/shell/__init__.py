"""The asyncio shell: the websockets server, HTTP routes (health, metrics, viewer,
the upgrade gate), the tick loop and the engine thread, JSON logs. It only moves
bytes between sockets and the pure core."""
