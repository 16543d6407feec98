"""The offline pipeline: ``motion`` (BVH, rigs, retargeting) -> ``dataset``
(trackers, features, contacts) -> ``nets`` (torch networks) -> ``train`` (training
and ONNX export into ``posecast/artifacts``) -> ``evaluation`` (``posecast eval``,
``posecast bench``). Needs the ``[data]``/``[train]`` extras; serving never imports it."""
