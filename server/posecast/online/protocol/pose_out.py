"""One shown pose on its way out: made once per pose per tick, encoded once per protocol.

::

    engine thread:  Shown poses --PoseState.batch, PoseOut.batch--> [PoseOut] (once)
    event loop:     PoseOut.v1()     -> the v1 ``pose`` message    (once, cached)
                    PoseOut.state    -> v2 records per reference   (posestream)
                    PoseOut.bus_row() / from_bus_rows() -> the cluster bus, and back

A :class:`PoseOut` holds what every way out needs and nothing decoded: the v1
quantities (root in metres, 1 mm offsets, snorm16 world rotations) and the v2
:class:`~posecast.online.protocol.records.PoseState` (0.1 mm root, the calibration
scale, reach flag). The cluster bus carries the quantised row, so a node that
receives another node's pose encodes it for its own v1 and v2 clients without
decoding a wire message or guessing the scale from bone lengths. Its v2 rotations are
then the snorm16 ones (within 1e-4 rad of the origin node's float64).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import msgpack
import numpy as np
from numpy.typing import NDArray

from posecast.geometry.rotations import quat_conj, quat_mul
from posecast.online.protocol import quantize
from posecast.online.protocol.messages import QUAT_TOLERANCE
from posecast.online.protocol.record_state import ROOT_MAX
from posecast.online.protocol.records import PoseState
from posecast.online.protocol.wire import pose_map
from posecast.skeleton import NUM_JOINTS, PARENTS

# One bus row: player, seq, t, v1 root (3 floats, m), offsets (108 B), rotations
# (152 B), v2 root (3 ints, 0.1 mm), scale, reach-limited.
BUS_ROW_LEN = 9
_PARENTS = np.array(PARENTS[1:])


@dataclass
class PoseOut:
    player: str
    seq: int
    t: float  # server time of the tick that made it (this node's clock)
    root: tuple[float, float, float]  # v1: the pelvis, metres
    offsets: bytes  # v1: the other joints from the pelvis, int16 mm (108 bytes)
    rotations: bytes  # v1: world rotations, snorm16 (152 bytes)
    state: PoseState  # v2: what records are prepared from
    _v1: bytes | None = field(default=None, repr=False)

    @classmethod
    def batch(
        cls, states: Sequence[PoseState | None], positions: NDArray[Any], rotations: NDArray[Any]
    ) -> tuple[list[PoseOut], int]:
        """The poses of ``states`` (:meth:`PoseState.batch` of the same engine output:
        ``positions (E, 19, 3)``, ``rotations (E, 19, 4)``) with their v1 quantities, in
        one numpy pass; with how many were refused (``None`` in ``states``: the pelvis
        beyond +-1000 m, or a joint beyond what v1 holds: 32 m from the pelvis)."""
        roots, offsets = quantize.pos2mm_many(np.asarray(positions, dtype=np.float64))
        rots = quantize.quat2snorm_many(np.asarray(rotations, dtype=np.float64))
        out: list[PoseOut] = []
        for st, r, off, rot in zip(states, roots, offsets, rots, strict=True):
            if st is not None and off is not None and rot is not None:
                out.append(cls(st.player, st.seq, st.t, (r[0], r[1], r[2]), off, rot, st))
        return out, len(states) - len(out)

    def v1(self) -> bytes:
        """The v1 ``pose`` message (encoded on first use, then shared by every v1 client)."""
        if self._v1 is None:
            root = list(self.root)
            m = pose_map(self.player, self.seq, self.t, root, self.offsets, self.rotations)
            self._v1 = msgpack.packb(m, use_bin_type=True)
        return self._v1

    def at(self, t: float) -> PoseOut:
        """The same pose stamped ``t`` (another node's clock mapped onto this one's)."""
        st = replace(self.state, t=t, _keyframe=None, _deltas={})
        return replace(self, t=t, state=st, _v1=None)

    def bus_row(self) -> list[Any]:
        st = self.state
        return [self.player, self.seq, self.t, list(self.root), self.offsets, self.rotations,
                list(st.root), st.scale, st.reach_limited]  # fmt: skip

    @classmethod
    def from_bus_row(cls, row: object) -> PoseOut | None:
        """A row another node published, or ``None`` when it is not one (checked field by
        field: a peer of another version, or a corrupt message, must not reach a client)."""
        poses = cls.from_bus_rows([row])
        return None if poses is None else poses[0]

    @classmethod
    def from_bus_rows(cls, rows: object) -> tuple[PoseOut, ...] | None:
        """The rows of one bus ``tick`` (a list of :meth:`bus_row`), or ``None`` when any
        is not a row: each checked field by field, then every pose's rotations checked
        and turned into v2 items in one numpy pass, as :meth:`PoseState.batch` does for
        the engine's poses (one pose at a time took 150 us, most of a receiving worker's
        bus time at 16 players)."""
        if not isinstance(rows, list) or not all(_is_row(r) for r in rows):
            return None
        if not rows:
            return ()
        blob = b"".join(r[5] for r in rows)
        snorm = np.frombuffer(blob, dtype=np.dtype("<i2")).reshape(len(rows), NUM_JOINTS, 4)
        q = snorm / quantize.ROT_SCALE  # (E, 19, 4)
        norms = np.sqrt(np.einsum("eij,eij->ei", q, q))  # (E, 19)
        if not (np.abs(norms - 1.0) <= QUAT_TOLERANCE).all():
            return None
        world = q / norms[..., None]
        items = world.copy()
        items[:, 1:] = quat_mul(quat_conj(world[:, _PARENTS]), world[:, 1:])
        out = []
        for i, (player, seq, t, root, off, rot, root01, scale, limited) in enumerate(rows):
            r01 = (root01[0], root01[1], root01[2])
            st = PoseState(player, seq, t, r01, items[i], world[i], scale, limited)
            out.append(cls(player, seq, t, (root[0], root[1], root[2]), off, rot, st))
        return tuple(out)


def _is_row(row: object) -> bool:
    """``row`` has a bus row's fields, each of its type and size (the pelvis within
    +-1000 m, the scale positive)."""
    if not isinstance(row, list) or len(row) != BUS_ROW_LEN:
        return False
    player, seq, t, root, off, rot, root01, scale, limited = row
    return bool(
        isinstance(player, str)
        and type(seq) is int
        and isinstance(t, float)
        and _floats3(root)
        and isinstance(off, bytes)
        and len(off) == quantize.POS_BYTES
        and isinstance(rot, bytes)
        and len(rot) == quantize.ROT_BYTES
        and _ints3(root01)
        and all(abs(c) <= ROOT_MAX for c in root01)
        and isinstance(scale, float)
        and np.isfinite(scale)
        and scale > 0
        and isinstance(limited, bool)
    )


def _floats3(v: object) -> bool:
    return (
        isinstance(v, list)
        and len(v) == 3
        and all(isinstance(x, float) and np.isfinite(x) for x in v)
    )


def _ints3(v: object) -> bool:
    return isinstance(v, list) and len(v) == 3 and all(type(x) is int for x in v)
