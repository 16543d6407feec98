/**
 * Pose quantisation for the wire (`proto/README.md`, "Position quantisation" and
 * "Rotation quantisation"); the same arithmetic as `posecast/online/protocol/quantize.py`,
 * so re-encoding a decoded pose gives its bytes back bit for bit.
 *
 * Positions: the PELVIS as three float64 (`root`), the other 18 joints as int16
 * millimetres relative to it, little-endian (108 bytes). Rotations: each xyzw
 * component times 32767, rounded half to even, int16 little-endian (152 bytes);
 * decoders divide by 32767 and do not renormalise.
 */

import { NotNormalisedError, OutOfRangeError } from "./errors.js";
import { NUM_JOINTS, QUAT_TOLERANCE } from "./messages.js";

export const POS_UNIT_M = 0.001;
export const ROT_SCALE = 32767;
export const POS_BYTES = (NUM_JOINTS - 1) * 3 * 2; // 108
export const ROT_BYTES = NUM_JOINTS * 4 * 2; // 152
const I16_MAX = 32767;

/** Round half to even, like numpy's `rint` (JS `Math.round` rounds half up). */
export function rint(x: number): number {
  const r = Math.round(x);
  return r - x === 0.5 && r % 2 !== 0 ? r - 1 : r;
}

/** World positions (57 = 19 x xyz, metres) -> `[root, 108 offset bytes]`. */
export function pos2mm(positions: ArrayLike<number>): [[number, number, number], Uint8Array] {
  if (positions.length !== NUM_JOINTS * 3) {
    throw new RangeError(`positions must hold ${NUM_JOINTS * 3} numbers`);
  }
  const root: [number, number, number] = [positions[0]!, positions[1]!, positions[2]!];
  const out = new Uint8Array(POS_BYTES);
  const view = new DataView(out.buffer);
  for (let i = 3; i < NUM_JOINTS * 3; i++) {
    const mm = rint((positions[i]! - root[i % 3]!) / POS_UNIT_M);
    if (!(Math.abs(mm) <= I16_MAX)) {
      throw new OutOfRangeError("a joint is more than 32.767 m from the pelvis", {
        field: "pos_mm",
      });
    }
    view.setInt16((i - 3) * 2, mm, true);
  }
  return [root, out];
}

/** `root` and 108 offset bytes -> world positions (57 numbers, metres). */
export function mm2pos(root: readonly number[], blob: Uint8Array): Float64Array {
  const view = new DataView(blob.buffer, blob.byteOffset, blob.byteLength);
  const out = new Float64Array(NUM_JOINTS * 3);
  out[0] = root[0]!;
  out[1] = root[1]!;
  out[2] = root[2]!;
  for (let i = 3; i < NUM_JOINTS * 3; i++) {
    out[i] = view.getInt16((i - 3) * 2, true) * POS_UNIT_M + root[i % 3]!;
  }
  return out;
}

/** Unit quaternions (76 = 19 x xyzw) -> 152 bytes of snorm16. */
export function quat2snorm(quats: ArrayLike<number>): Uint8Array {
  if (quats.length !== NUM_JOINTS * 4) {
    throw new RangeError(`rotations must hold ${NUM_JOINTS * 4} numbers`);
  }
  const out = new Uint8Array(ROT_BYTES);
  const view = new DataView(out.buffer);
  for (let i = 0; i < NUM_JOINTS * 4; i++) {
    const s = rint(quats[i]! * ROT_SCALE);
    if (!(Math.abs(s) <= I16_MAX)) {
      throw new NotNormalisedError("a rotation is not a unit quaternion", { field: "rot" });
    }
    view.setInt16(i * 2, s, true);
  }
  return out;
}

/** 152 bytes of snorm16 -> quaternions (76 numbers, xyzw, not renormalised). */
export function snorm2quat(blob: Uint8Array): Float64Array {
  const view = new DataView(blob.buffer, blob.byteOffset, blob.byteLength);
  const q = new Float64Array(NUM_JOINTS * 4);
  for (let i = 0; i < NUM_JOINTS * 4; i++) q[i] = view.getInt16(i * 2, true) / ROT_SCALE;
  for (let j = 0; j < NUM_JOINTS; j++) {
    const x = q[4 * j]!;
    const y = q[4 * j + 1]!;
    const z = q[4 * j + 2]!;
    const w = q[4 * j + 3]!;
    const n = Math.sqrt(x * x + y * y + z * z + w * w);
    if (!(Math.abs(n - 1) <= QUAT_TOLERANCE)) {
      throw new NotNormalisedError(`rotation of joint ${j} has norm ${n.toFixed(6)}`, {
        field: "rot",
      });
    }
  }
  return q;
}
