"""The bus between posecast nodes: ``bus`` (the interface and wire format),
``memory`` and ``redis_bus``/``redis_store`` (the backends), ``auto`` (the factory)."""
