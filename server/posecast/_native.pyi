# Types of the native SSI kernels (server/native/: the module is pc_module.c; built by setup.py).
from typing import Any

def isa() -> str: ...
def isas() -> tuple[str, ...]: ...
def set_isa(level: str, /) -> None: ...
def precision() -> str: ...
def set_precision(precision: str, /) -> None: ...
def set_threads(n: int, /) -> None: ...
def threads() -> int: ...
def pack_decoder(
    F: int,
    H: int,
    n_rot: int,
    n_root: int,
    mean: Any,
    inv_std: Any,
    wx: Any,
    bfc: Any,
    wih: Any,
    bih: Any,
    whh: Any,
    bhh: Any,
    whead: Any,
    bhead: Any,
    bf16: bool,
    /,
) -> object: ...
def pack_pool(offsets: Any, mean: Any, inv_std: Any, layers: list[Any], /) -> object: ...
def decode(
    packed: object,
    features: Any,
    group: int,
    cache: Any,
    h: Any,
    rotations: Any,
    root: Any | None,
    contacts: Any,
    h_out: Any,
    /,
) -> None: ...
def pool(
    packed: object,
    rotations: Any,
    contacts: Any,
    root_mat: Any,
    root_pos: Any,
    group: int,
    locked: Any,
    lock_pos: Any,
    release: Any,
    suppressed: Any,
    release_frames: int,
    max_drift: float,
    world_out: Any,
    scores: Any,
    /,
) -> None: ...
def upper_body(
    positions: Any,
    rotations: Any,
    tracker_pos: Any,
    tracker_quat: Any,
    free_root: Any,
    wrist_share: float,
    lean_share: float,
    neck_share: float,
    spine_reach: float,
    reach_tol: float,
    offsets: Any,
    positions_out: Any,
    rotations_out: Any,
    reach_limited: Any,
    /,
) -> None: ...
def hinge(
    positions: Any,
    rotations: Any,
    limbs: Any,
    straight: float,
    span: float,
    flip: float,
    flip_span: float,
    /,
) -> None: ...
def emit(
    packed: object,
    rotations: Any,
    contacts: Any,
    root_mat: Any,
    root_pos: Any,
    locked: Any,
    lock_pos: Any,
    release: Any,
    suppressed: Any,
    release_frames: int,
    max_drift: float,
    positions: Any,
    rotations_out: Any,
    /,
) -> None: ...
def pool_stats() -> tuple[int, ...]: ...
def encode_deltas(
    parents: Any,
    seq: Any,
    ref_seq: Any,
    flags: Any,
    ref_items: Any,
    step_rot: Any,
    world: Any,
    ref_root: Any,
    step_root: Any,
    root: Any,
    new_items: Any,
    d_rot: Any,
    body: Any,
    length: Any,
    /,
) -> None: ...
