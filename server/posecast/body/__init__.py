"""The shown pose: the passes that turn a decoded sample into the body that is streamed.

One function runs them in their order, :func:`posecast.body.pipeline.show`; the online
engine calls it on the players it emits each tick, and the offline evaluation on its
clips frame by frame, so the evaluation measures what is streamed. This package is
below both: it imports neither ``posecast.online`` nor ``posecast.offline``
(``tests/body/test_purity.py``), only numpy and the skeleton, geometry and tracking
modules. Where its heaviest passes run (numpy here, or a backend's C) is a
:class:`posecast.body.passes.Passes`, which the backend chosen by name supplies.
"""
