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

import { NUM_JOINTS } from "../src/messages.js";
import { bodyScale } from "../src/rest.js";

// The rest pose and the fit helpers live in the SDK (`src/rest.ts`, shipped with the
// three.js binding, `@posecast/client/three`); re-exported for the viewer's modules.
export { REFERENCE_OFFSETS_M, REST_POSITIONS_M } from "../src/rest.js";

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
  out.scale = bodyScale(positions);
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
