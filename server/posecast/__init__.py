"""posecast: full-body avatars from 4 tracked points, streamed to every player in a room.

The package follows the data path:

* :mod:`posecast.skeleton` and :mod:`posecast.geometry` - the canonical body and its math
* :mod:`posecast.offline.motion` - BVH in and out, retargeting onto the canonical skeleton
* :mod:`posecast.tracking.features` - tracker slots and the network's input features
* :mod:`posecast.offline.dataset` - cached training data: trackers, features, contact labels
"""

__version__ = "0.1.0"
