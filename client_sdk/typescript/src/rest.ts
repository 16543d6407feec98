/**
 * The reference body's rest pose and the helpers that fit a body to a player's skeleton:
 * plain arrays in, plain arrays out (no three.js, no wire format). The three.js binding
 * (`@posecast/client/three`) and the live viewer build on them; they are not part of the
 * core entry point, whose bundle they would otherwise grow.
 *
 * Conventions (`server/posecast/skeleton.py`, `proto/README.md`): metres, +Y up, the
 * character faces +Z in its rest pose (a T-pose, every local rotation identity), its
 * left is +X. Joint j sits at `p[parent] + R_world[parent] * offset[j]`.
 */

import { NUM_JOINTS, PARENTS } from "./messages.js";

type Vec3 = readonly [number, number, number];

/**
 * Rest offsets of the reference body (head joint 1.60 m up, about 1.75 m tall) from each
 * joint's parent, metres, joint order: a copy of `_REFERENCE_OFFSETS_M` in
 * `server/posecast/skeleton.py` (tests/system/test_viewer.py compares the two).
 */
export const REFERENCE_OFFSETS_M: readonly Vec3[] = [
  [0.0, 0.0, 0.0], // PELVIS
  [0.0, 0.1, 0.0], // SPINE
  [0.0, 0.2, 0.0], // CHEST
  [0.0, 0.22, 0.0], // NECK
  [0.0, 0.1, 0.0], // HEAD
  [0.17, 0.17, 0.0], // LEFT_UPPER_ARM
  [0.28, 0.0, 0.0], // LEFT_FOREARM
  [0.25, 0.0, 0.0], // LEFT_HAND
  [-0.17, 0.17, 0.0], // RIGHT_UPPER_ARM
  [-0.28, 0.0, 0.0], // RIGHT_FOREARM
  [-0.25, 0.0, 0.0], // RIGHT_HAND
  [0.09, -0.05, 0.0], // LEFT_THIGH
  [0.0, -0.43, 0.0], // LEFT_SHIN
  [0.0, -0.42, 0.0], // LEFT_FOOT
  [0.0, -0.06, 0.13], // LEFT_TOE
  [-0.09, -0.05, 0.0], // RIGHT_THIGH
  [0.0, -0.43, 0.0], // RIGHT_SHIN
  [0.0, -0.42, 0.0], // RIGHT_FOOT
  [0.0, -0.06, 0.13], // RIGHT_TOE
];

/** The reference offsets as one flat array, 19 x 3 (the layout `skeletonOf` returns). */
export const REFERENCE_OFFSETS_FLAT_M: Float64Array = Float64Array.from(REFERENCE_OFFSETS_M.flat());

/**
 * Rest (T-pose) joint positions with the pelvis at the origin, metres, 19 x 3.
 *
 * @param offsets bone offsets from each joint's parent, 19 x 3 (a player's announced
 *   skeleton, `PosecastClient.skeletonOf`); the reference body's when absent.
 */
export function restPositions(offsets: ArrayLike<number> = REFERENCE_OFFSETS_FLAT_M): Float64Array {
  if (offsets.length !== 3 * NUM_JOINTS) throw new RangeError("restPositions wants 19 x 3 offsets");
  const rest = new Float64Array(3 * NUM_JOINTS);
  for (let j = 1; j < NUM_JOINTS; j++) {
    const p = PARENTS[j]!;
    for (let k = 0; k < 3; k++) rest[3 * j + k] = rest[3 * p + k]! + offsets[3 * j + k]!;
  }
  return rest;
}

/** The reference body's rest positions (pelvis at the origin), 19 x 3: the viewer's bind pose. */
export const REST_POSITIONS_M: Float64Array = restPositions();

/** The sum of the 18 bone lengths of a skeleton given by its offsets, metres. */
export function boneSum(offsets: ArrayLike<number>): number {
  let sum = 0;
  for (let j = 1; j < NUM_JOINTS; j++) sum += Math.hypot(offsets[3 * j]!, offsets[3 * j + 1]!, offsets[3 * j + 2]!);
  return sum;
}

/** The sum of the reference body's 18 bone lengths, metres. */
export const REFERENCE_BONE_SUM_M: number = boneSum(REFERENCE_OFFSETS_FLAT_M);

/**
 * A body's size against the reference body, from a pose's joint positions (19 x 3):
 * the ratio of the sum of its bone lengths to the reference body's (a player's
 * calibration scales the whole body alike, so one number fits every bone); 1 for a
 * degenerate pose. Allocates nothing.
 */
export function bodyScale(positions: ArrayLike<number>): number {
  let bones = 0;
  for (let j = 1; j < NUM_JOINTS; j++) {
    const p = PARENTS[j]!;
    bones += Math.hypot(
      positions[3 * j]! - positions[3 * p]!,
      positions[3 * j + 1]! - positions[3 * p + 1]!,
      positions[3 * j + 2]! - positions[3 * p + 2]!,
    );
  }
  return bones > 1e-6 ? bones / REFERENCE_BONE_SUM_M : 1;
}

/**
 * The height of the pelvis over the soles in the rest pose, metres: the vertical drop
 * from the pelvis to the lower toe joint (the reference body: 0.96 m).
 */
export function hipsHeight(offsets: ArrayLike<number> = REFERENCE_OFFSETS_FLAT_M): number {
  const rest = restPositions(offsets);
  let low = 0;
  for (let j = 0; j < NUM_JOINTS; j++) low = Math.min(low, rest[3 * j + 1]!);
  return -low;
}

/**
 * A skeleton's offsets (19 x 3) read off one pose, for a player whose skeleton was never
 * announced (protocol v1): each joint's position from its parent, turned back into the
 * parent's rest frame by the parent's world rotation (`offset[j] = R[parent]^-1 (p[j] -
 * p[parent])`). With `rotations` absent, the reference offsets scaled by
 * {@link bodyScale}.
 */
export function offsetsFromPose(positions: ArrayLike<number>, rotations?: ArrayLike<number>): Float64Array {
  if (positions.length !== 3 * NUM_JOINTS) throw new RangeError("offsetsFromPose wants 19 x 3 positions");
  const out = new Float64Array(3 * NUM_JOINTS);
  if (rotations === undefined || rotations.length !== 4 * NUM_JOINTS) {
    const s = bodyScale(positions);
    for (let i = 0; i < out.length; i++) out[i] = REFERENCE_OFFSETS_FLAT_M[i]! * s;
    return out;
  }
  for (let j = 1; j < NUM_JOINTS; j++) {
    const p = PARENTS[j]!;
    const [vx, vy, vz] = [
      positions[3 * j]! - positions[3 * p]!,
      positions[3 * j + 1]! - positions[3 * p + 1]!,
      positions[3 * j + 2]! - positions[3 * p + 2]!,
    ];
    // v' = q^-1 v q for the unit quaternion q = (x, y, z, w) of the parent.
    const n = Math.hypot(rotations[4 * p]!, rotations[4 * p + 1]!, rotations[4 * p + 2]!, rotations[4 * p + 3]!) || 1;
    const [x, y, z, w] = [-rotations[4 * p]! / n, -rotations[4 * p + 1]! / n, -rotations[4 * p + 2]! / n, rotations[4 * p + 3]! / n];
    const [tx, ty, tz] = [2 * (y * vz - z * vy), 2 * (z * vx - x * vz), 2 * (x * vy - y * vx)];
    out[3 * j] = vx + w * tx + (y * tz - z * ty);
    out[3 * j + 1] = vy + w * ty + (z * tx - x * tz);
    out[3 * j + 2] = vz + w * tz + (x * ty - y * tx);
  }
  return out;
}
