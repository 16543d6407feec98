/**
 * From a pose to the skinned avatar's bone transforms: plain arrays in, plain arrays out
 * (no three.js, no wire format), so that any source of poses can drive the mesh. v1
 * poses carry world positions and world rotations; a source with local rotations and a
 * skeleton runs its FK first and hands the result to {@link poseToBones}.
 *
 * Conventions (`server/posecast/skeleton.py`, `proto/README.md`): metres, +Y up, the
 * character faces +Z in its rest pose (a T-pose, every local rotation identity), its
 * left is +X; quaternions are xyzw and turn a joint's frame into the world's. Joint j
 * sits at `p[parent] + R_world[parent] * offset[j]`: the bone that starts at joint j
 * carries its children's offsets in joint j's own frame, so the bone's world transform
 * is simply (position p[j], rotation R_world[j], the body's scale).
 */

import { NUM_JOINTS, PARENTS } from "../src/messages.js";

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

/** Rest (T-pose) joint positions with the pelvis at the origin, metres, 19 x 3: the bind pose. */
export const REST_POSITIONS_M: Float64Array = (() => {
  const rest = new Float64Array(3 * NUM_JOINTS);
  for (let j = 1; j < NUM_JOINTS; j++) {
    const p = PARENTS[j]!;
    for (let k = 0; k < 3; k++) rest[3 * j + k] = rest[3 * p + k]! + REFERENCE_OFFSETS_M[j]![k]!;
  }
  return rest;
})();

/** The sum of the reference body's 18 bone lengths, metres. */
const REFERENCE_BONE_SUM_M = REFERENCE_OFFSETS_M.reduce((sum, [x, y, z]) => sum + Math.hypot(x, y, z), 0);

/** Each bone's world transform: the skinned mesh's bone j is placed by entry j. */
export interface BoneTransforms {
  /** Bone origins (the joints), world metres, 19 x 3. */
  readonly positions: Float64Array;
  /** Bone rotations, world, unit xyzw, 19 x 4. */
  readonly rotations: Float64Array;
  /** The body's size against the reference body (1: the 1.75 m body), every bone alike. */
  scale: number;
}

export function emptyBones(): BoneTransforms {
  return { positions: new Float64Array(3 * NUM_JOINTS), rotations: new Float64Array(4 * NUM_JOINTS), scale: 1 };
}

/**
 * Bone transforms for a pose.
 *
 * @param positions world joint positions, metres, 19 x 3 (joint order).
 * @param worldRotations world joint rotations, xyzw, 19 x 4; renormalised here (v1
 *   decoders leave them within 3.1e-5 of unit length).
 * @param out reused when given (one per avatar: no allocation per frame).
 * @returns bone j at `positions[j]`, turned by `worldRotations[j]`, scaled by the
 *   body's size: the mean ratio of the pose's bone lengths to the reference body's (a
 *   player's calibration scales the whole body alike, so one number fits every bone).
 */
export function poseToBones(
  positions: ArrayLike<number>,
  worldRotations: ArrayLike<number>,
  out: BoneTransforms = emptyBones(),
): BoneTransforms {
  if (positions.length !== 3 * NUM_JOINTS || worldRotations.length !== 4 * NUM_JOINTS) {
    throw new RangeError(`poseToBones wants 19 x 3 positions and 19 x 4 rotations`);
  }
  let bones = 0;
  for (let j = 1; j < NUM_JOINTS; j++) {
    const p = PARENTS[j]!;
    bones += Math.hypot(
      positions[3 * j]! - positions[3 * p]!,
      positions[3 * j + 1]! - positions[3 * p + 1]!,
      positions[3 * j + 2]! - positions[3 * p + 2]!,
    );
  }
  out.scale = bones > 1e-6 ? bones / REFERENCE_BONE_SUM_M : 1;
  for (let i = 0; i < 3 * NUM_JOINTS; i++) out.positions[i] = positions[i]!;
  for (let j = 0; j < NUM_JOINTS; j++) {
    const i = 4 * j;
    const [x, y, z, w] = [worldRotations[i]!, worldRotations[i + 1]!, worldRotations[i + 2]!, worldRotations[i + 3]!];
    const n = Math.hypot(x, y, z, w);
    const s = n > 1e-9 ? 1 / n : 0;
    out.rotations.set(s === 0 ? [0, 0, 0, 1] : [x * s, y * s, z * s, w * s], i);
  }
  return out;
}
