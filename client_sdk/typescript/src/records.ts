/**
 * Protocol v2 pose records, decoded (pure): `poses.data` bytes in, avatar states out.
 *
 * Written from `proto/README.md` ("Pose records"), apart from the server's encoder and
 * the Python SDK's decoder; the stream vectors in `proto/vectors/poses.json` keep the
 * three in step. A record is:
 *
 * ```text
 * avatar id (unsigned LEB128) | flags (u8: bit 0 keyframe, bit 1 reach_limited)
 * keyframe: seq u32 LE | root 3 x i32 LE (0.1 mm) | 19 x 48-bit smallest-three
 * delta:    seq step u8 (1..255) | bitstream (LSB first) of 20 items, root then the
 *           19 rotations: a 2-bit class, then 3 signed components of its width
 * ```
 *
 * Items are the PELVIS world rotation, then each joint's rotation relative to its
 * parent (joint order). Each item keeps its last step `v`; a delta component `r` gives
 * `root += v + r` (0.1 mm) and `q = normalise((q * exp(v * STEP)) * exp(r * STEP))` for a
 * rotation, then `v = v + r`. A keyframe resets every `v` to 0. Quaternions are xyzw.
 */

import { BadFieldError } from "./errors.js";
import { NUM_JOINTS, PARENTS, SKELETON_BYTES } from "./messages.js";

export const ROOT_UNIT_M = 1e-4;
export const SKELETON_UNIT_M = 1e-4;
export const ROT_STEP_RAD = 2 ** -9;
export const SMALLEST3_SCALE = 23168;
const ROT_WIDTHS = [0, 4, 7, 12] as const; // bits per component, by class
const ROOT_WIDTHS = [0, 5, 8, 14] as const;
const KEYFRAME = 0x01;
const REACH_LIMITED = 0x02;
const KEYFRAME_BYTES = 130; // after the flags
const ROOT_MAX = 10_000_000; // 1000 m in 0.1 mm
const ITEMS = NUM_JOINTS + 1; // the root, then 19 rotations

/** What this client holds for one avatar: the result of its last record. */
export interface AvatarState {
  readonly seq: number;
  /** PELVIS world position, ints in 0.1 mm (3). */
  readonly root: Int32Array;
  /** PELVIS world rotation, then local rotations, xyzw (19 x 4 = 76). */
  readonly items: Float64Array;
  /** Each item's last step, ints (20 x 3 = 60: the root's, then the rotations'). */
  readonly steps: Int32Array;
}

export interface DecodedRecord {
  readonly avatarId: number;
  readonly keyframe: boolean;
  readonly reachLimited: boolean;
  readonly state: AvatarState;
}

/** A v2 skeleton (108 bytes) -> bone offsets, metres, 19 x 3 (row 0, PELVIS, zero). */
export function skeleton2offsets(blob: Uint8Array): Float64Array {
  if (blob.length !== SKELETON_BYTES) throw new RangeError(`a skeleton is ${SKELETON_BYTES} bytes`);
  const view = new DataView(blob.buffer, blob.byteOffset, blob.byteLength);
  const out = new Float64Array(NUM_JOINTS * 3);
  for (let i = 0; i < (NUM_JOINTS - 1) * 3; i++) out[3 + i] = view.getInt16(2 * i, true) * SKELETON_UNIT_M;
  return out;
}

/** Hamilton product `a * b` of xyzw quaternions at `a[ai..]`, `b[bi..]`, into `out[oi..]`. */
function mulInto(
  a: ArrayLike<number>,
  ai: number,
  b: ArrayLike<number>,
  bi: number,
  out: Float64Array,
  oi: number,
): void {
  const ax = a[ai]!, ay = a[ai + 1]!, az = a[ai + 2]!, aw = a[ai + 3]!; // prettier-ignore
  const bx = b[bi]!, by = b[bi + 1]!, bz = b[bi + 2]!, bw = b[bi + 3]!; // prettier-ignore
  out[oi] = aw * bx + ax * bw + ay * bz - az * by;
  out[oi + 1] = aw * by - ax * bz + ay * bw + az * bx;
  out[oi + 2] = aw * bz + ax * by - ay * bx + az * bw;
  out[oi + 3] = aw * bw - ax * bx - ay * by - az * bz;
}

/** A rotation vector (radians) -> quaternion: `(u sin(t/2) / t, cos(t/2))`, t = |u|. */
function expInto(ux: number, uy: number, uz: number, out: Float64Array): void {
  const t = Math.sqrt(ux * ux + uy * uy + uz * uz);
  if (t > 0) {
    const s = Math.sin(t / 2) / t;
    out[0] = ux * s;
    out[1] = uy * s;
    out[2] = uz * s;
    out[3] = Math.cos(t / 2);
  } else {
    out[0] = 0;
    out[1] = 0;
    out[2] = 0;
    out[3] = 1;
  }
}

/** Items (PELVIS world, then local rotations; 19 x 4) -> world rotations (19 x 4). */
export function items2world(items: ArrayLike<number>): Float64Array {
  const w = Float64Array.from(items);
  for (let j = 1; j < NUM_JOINTS; j++) mulInto(w, 4 * PARENTS[j]!, items, 4 * j, w, 4 * j);
  return w;
}

/**
 * Joint positions by FK, metres (19 x 3): `position[j] = position[parent] +
 * R(world[parent]) @ offset[j]`, with the root in metres and the bone offsets of
 * {@link skeleton2offsets}. The rotation matrix is built from the quaternion as it is
 * (not renormalised), like the Python SDK's.
 */
export function fk(world: ArrayLike<number>, root: ArrayLike<number>, offsets: ArrayLike<number>): Float64Array {
  const pos = new Float64Array(NUM_JOINTS * 3);
  pos[0] = root[0]!;
  pos[1] = root[1]!;
  pos[2] = root[2]!;
  for (let j = 1; j < NUM_JOINTS; j++) {
    const p = PARENTS[j]!;
    const x = world[4 * p]!, y = world[4 * p + 1]!, z = world[4 * p + 2]!, s = world[4 * p + 3]!; // prettier-ignore
    const ox = offsets[3 * j]!, oy = offsets[3 * j + 1]!, oz = offsets[3 * j + 2]!; // prettier-ignore
    pos[3 * j] = pos[3 * p]! + ((1 - 2 * (y * y + z * z)) * ox + 2 * (x * y - z * s) * oy + 2 * (x * z + y * s) * oz);
    pos[3 * j + 1] =
      pos[3 * p + 1]! + (2 * (x * y + z * s) * ox + (1 - 2 * (x * x + z * z)) * oy + 2 * (y * z - x * s) * oz);
    pos[3 * j + 2] =
      pos[3 * p + 2]! + (2 * (x * z - y * s) * ox + 2 * (y * z + x * s) * oy + (1 - 2 * (x * x + y * y)) * oz);
  }
  return pos;
}

/** An avatar's root in metres (3). */
export function rootMetres(state: AvatarState): Float64Array {
  return Float64Array.from(state.root, (v) => v * ROOT_UNIT_M);
}

function bad(message: string): BadFieldError {
  return new BadFieldError(message, { field: "data" });
}

function leb128(data: Uint8Array, pos: number): [number, number] {
  let value = 0;
  for (let k = 0; k < 5; k++) {
    if (pos + k >= data.length) throw bad("a record is cut short in its avatar id");
    const b = data[pos + k]!;
    value += (b & 0x7f) * 2 ** (7 * k);
    if (!(b & 0x80)) {
      if (k > 0 && b === 0) throw bad("an avatar id that is not minimal LEB128");
      if (value > 0xffffffff) throw bad("an avatar id over 2**32 - 1");
      return [value, pos + k + 1];
    }
  }
  throw bad("an avatar id of more than 5 bytes");
}

/** One 48-bit smallest-three word (at `data[pos..pos+6]`) into `out[oi..oi+4]`. */
function smallest3(data: Uint8Array, pos: number, out: Float64Array, oi: number): void {
  const lo = data[pos]! | (data[pos + 1]! << 8) | (data[pos + 2]! << 16); // bits 0-23
  const hi = data[pos + 3]! | (data[pos + 4]! << 8) | (data[pos + 5]! << 16); // bits 24-47
  if (hi & 0x800000) throw bad("bit 47 of a keyframe rotation is set");
  const word = lo + hi * 2 ** 24; // < 2**47: exact in a double
  const comp = (n: number): number => {
    const bits = Math.floor(word / 2 ** (15 * n)) % 0x8000;
    return (bits >= 0x4000 ? bits - 0x8000 : bits) / SMALLEST3_SCALE;
  };
  const a = comp(0), b = comp(1), c = comp(2); // prettier-ignore
  const k = (hi >> 21) & 3; // bits 45-46
  const rest = [a, b, c];
  rest.splice(k, 0, Math.sqrt(Math.max(0, 1 - (a * a + b * b + c * c))));
  for (let i = 0; i < 4; i++) out[oi + i] = rest[i]!;
}

/** Reads a delta's bitstream, least significant bit first; past the end is "cut short". */
class BitReader {
  private bit = 0;
  constructor(
    private readonly data: Uint8Array,
    private readonly start: number,
  ) {}

  read(width: number): number {
    let v = 0;
    for (let i = 0; i < width; i++, this.bit++) {
      const at = this.start + (this.bit >> 3);
      if (at >= this.data.length) throw bad("a delta record is cut short");
      v |= ((this.data[at]! >> (this.bit & 7)) & 1) << i;
    }
    return v;
  }

  signed(width: number): number {
    const v = this.read(width);
    return v >= 1 << (width - 1) ? v - (1 << width) : v;
  }

  /** The byte after the stream (padded to a whole byte). */
  get end(): number {
    return this.start + ((this.bit + 7) >> 3);
  }
}

function applyDelta(data: Uint8Array, pos: number, prev: AvatarState): [AvatarState, number] {
  if (pos >= data.length || data[pos] === 0) throw bad("a delta's seq step is missing or zero");
  const seq = (prev.seq + data[pos]!) % 2 ** 32;
  const bits = new BitReader(data, pos + 1);
  const residuals = new Int32Array(ITEMS * 3);
  for (let item = 0; item < ITEMS; item++) {
    const w = (item === 0 ? ROOT_WIDTHS : ROT_WIDTHS)[bits.read(2)]!;
    if (w === 0) continue;
    for (let c = 0; c < 3; c++) residuals[3 * item + c] = bits.signed(w);
  }
  const root = new Int32Array(3);
  for (let c = 0; c < 3; c++) {
    const r = prev.root[c]! + prev.steps[c]! + residuals[c]!;
    if (!(Math.abs(r) <= ROOT_MAX)) throw bad("a delta takes the root beyond 1000 m");
    root[c] = r;
  }
  const steps = new Int32Array(ITEMS * 3);
  for (let i = 0; i < ITEMS * 3; i++) steps[i] = prev.steps[i]! + residuals[i]!;
  const items = new Float64Array(NUM_JOINTS * 4);
  const ev = new Float64Array(4);
  const er = new Float64Array(4);
  const tmp = new Float64Array(4);
  for (let j = 0; j < NUM_JOINTS; j++) {
    const v = 3 * (j + 1); // the rotation items follow the root's
    expInto(prev.steps[v]! * ROT_STEP_RAD, prev.steps[v + 1]! * ROT_STEP_RAD, prev.steps[v + 2]! * ROT_STEP_RAD, ev);
    expInto(residuals[v]! * ROT_STEP_RAD, residuals[v + 1]! * ROT_STEP_RAD, residuals[v + 2]! * ROT_STEP_RAD, er);
    mulInto(prev.items, 4 * j, ev, 0, tmp, 0);
    mulInto(tmp, 0, er, 0, items, 4 * j);
    const x = items[4 * j]!, y = items[4 * j + 1]!, z = items[4 * j + 2]!, s = items[4 * j + 3]!; // prettier-ignore
    const n = Math.sqrt(x * x + y * y + z * z + s * s);
    for (let c = 0; c < 4; c++) items[4 * j + c] = items[4 * j + c]! / n;
  }
  return [{ seq, root, items, steps }, bits.end];
}

/**
 * Every record of `data`, each applied to `avatars` (avatar id -> state, `null` for an
 * announced avatar without a keyframe yet), which it updates record by record. The
 * decoded records are appended to `out` as they come, so when a record is bad the
 * ones before it are there (and applied), as the spec's "skip the rest" asks.
 *
 * @throws BadFieldError (field `data`) a record is cut short, has reserved bits set,
 *   names an avatar id not in `avatars`, is a delta with nothing to apply to, or takes the
 *   root beyond 1000 m. The client skips the rest of the message and sends `resync`.
 */
export function decodeRecords(
  data: Uint8Array,
  avatars: Map<number, AvatarState | null>,
  out: DecodedRecord[] = [],
): DecodedRecord[] {
  let pos = 0;
  while (pos < data.length) {
    let avatarId: number;
    [avatarId, pos] = leb128(data, pos);
    if (!avatars.has(avatarId)) throw bad(`avatar id ${avatarId} was never announced`);
    if (pos >= data.length) throw bad("a record ends after its avatar id");
    const flags = data[pos++]!;
    if (flags & ~(KEYFRAME | REACH_LIMITED)) throw bad(`reserved record flags 0x${flags.toString(16)}`);
    let state: AvatarState;
    if (flags & KEYFRAME) {
      if (pos + KEYFRAME_BYTES > data.length) throw bad("a keyframe record is cut short");
      const view = new DataView(data.buffer, data.byteOffset + pos, KEYFRAME_BYTES);
      const root = Int32Array.of(view.getInt32(4, true), view.getInt32(8, true), view.getInt32(12, true));
      if (!root.every((v) => Math.abs(v) <= ROOT_MAX)) throw bad("a keyframe root beyond 1000 m");
      const items = new Float64Array(NUM_JOINTS * 4);
      for (let j = 0; j < NUM_JOINTS; j++) smallest3(data, pos + 16 + 6 * j, items, 4 * j);
      state = { seq: view.getUint32(0, true), root, items, steps: new Int32Array(ITEMS * 3) };
      pos += KEYFRAME_BYTES;
    } else {
      const prev = avatars.get(avatarId);
      if (prev === null || prev === undefined) throw bad(`a delta for avatar id ${avatarId} before its keyframe`);
      [state, pos] = applyDelta(data, pos, prev);
    }
    avatars.set(avatarId, state);
    out.push({ avatarId, keyframe: (flags & KEYFRAME) !== 0, reachLimited: (flags & REACH_LIMITED) !== 0, state });
  }
  return out;
}
