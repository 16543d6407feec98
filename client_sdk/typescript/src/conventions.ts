/**
 * Engine conventions: a posecast pose in Unity's, Unreal's and three.js's frames, and
 * posecast's 19 joints by their Unity, VRM and Unreal mannequin bone names. The same
 * tables as the Python SDK's `posecast_client.conventions`, checked by the shared
 * vectors `proto/vectors/sdk/conventions.json`; the reasoning is in `docs/game-engines.md`.
 *
 * posecast's world is right-handed, +Y up, metres; a character faces +Z and its left
 * is +X; quaternions are xyzw. Each engine is a change of basis
 * `p_engine = scale * BASIS * p_posecast` that keeps up, forward and the character's
 * right where the engine expects them:
 *
 * | engine | handedness | up, forward | position | quaternion xyzw |
 * |---|---|---|---|---|
 * | unity | left | +Y, +Z | (-x, y, z) | (x, -y, -z, w) |
 * | unreal | left | +Z, +X | 100 (z, -x, y) cm | (-z, x, -y, w) |
 * | three | right (same) | +Y, +Z | unchanged | unchanged |
 *
 * three.js, WebXR reference spaces and glTF share posecast's frame; only a WebXR
 * viewer (a camera) looks down -Z where a posecast head faces +Z: see
 * {@link headToXRView}. A joint's rotation is the turn from the T-pose rest to now; an
 * engine bone with its own T-pose world rotation `rest` takes `quatToEngine(q) * rest`.
 */

import { JOINT_NAMES, type JointName } from "./messages.js";

export const ENGINES = ["unity", "unreal", "three"] as const;
export type Engine = (typeof ENGINES)[number];

export interface EngineFrame {
  /** 3x3 row-major: row i is the engine's axis i in posecast coordinates. */
  readonly basis: readonly number[];
  /** Engine length units per metre. */
  readonly scale: number;
  readonly rightHanded: boolean;
}

export const ENGINE_FRAMES: Readonly<Record<Engine, EngineFrame>> = {
  // Unity: posecast's character right (-X) becomes +X; up and forward stay.
  unity: { basis: [-1, 0, 0, 0, 1, 0, 0, 0, 1], scale: 1, rightHanded: false },
  // Unreal: X forward (posecast +Z), Y right (posecast -X), Z up (posecast +Y).
  unreal: { basis: [0, 0, 1, -1, 0, 0, 0, 1, 0], scale: 100, rightHanded: false },
  three: { basis: [1, 0, 0, 0, 1, 0, 0, 0, 1], scale: 1, rightHanded: true },
};

function frame(engine: Engine): EngineFrame {
  const f = ENGINE_FRAMES[engine];
  if (f === undefined) throw new RangeError(`unknown engine ${String(engine)}`);
  return f;
}

/** `out[i] = sum_k m[i][k] * v[k]` for every 3-vector in `v` (`transpose`: m^T). */
function apply(
  m: readonly number[],
  v: ArrayLike<number>,
  stride: number,
  scale: number,
  transpose: boolean,
): Float64Array {
  const out = Float64Array.from(v);
  for (let j = 0; j < v.length; j += stride) {
    for (let i = 0; i < 3; i++) {
      let s = 0;
      for (let k = 0; k < 3; k++) s += (transpose ? m[k * 3 + i]! : m[i * 3 + k]!) * v[j + k]!;
      out[j + i] = s * scale;
    }
  }
  return out;
}

/** posecast positions (3 * J, metres) in the engine's frame and units. */
export function posToEngine(p: ArrayLike<number>, engine: Engine): Float64Array {
  const f = frame(engine);
  return apply(f.basis, p, 3, f.scale, false);
}

/** Engine positions (3 * J) in posecast metres: the inverse of {@link posToEngine}. */
export function engineToPos(p: ArrayLike<number>, engine: Engine): Float64Array {
  const f = frame(engine);
  return apply(f.basis, p, 3, 1 / f.scale, true);
}

/**
 * posecast rotations (4 * J, xyzw) in the engine's xyzw (Unity `Quaternion`, Unreal
 * `FQuat`, `THREE.Quaternion`): a mirror basis turns the axis into `-BASIS * axis`.
 */
export function quatToEngine(q: ArrayLike<number>, engine: Engine): Float64Array {
  const f = frame(engine);
  return apply(f.basis, q, 4, f.rightHanded ? 1 : -1, false);
}

/** Engine rotations (4 * J, xyzw) in posecast xyzw: the inverse of {@link quatToEngine}. */
export function engineToQuat(q: ArrayLike<number>, engine: Engine): Float64Array {
  const f = frame(engine);
  return apply(f.basis, q, 4, f.rightHanded ? 1 : -1, true);
}

/**
 * A posecast head (or tracker) rotation (4 * J, xyzw) as the orientation of a WebXR
 * viewer or three.js camera at it: turned 180 degrees about its own Y (`q * (0, 1, 0,
 * 0)`), since a camera looks down its -Z and a posecast head faces +Z. The inverse of
 * `xrToPosecast`'s orientation map, which is the same map (up to the sign of q).
 */
export function headToXRView(q: ArrayLike<number>): Float64Array {
  const out = new Float64Array(q.length);
  for (let j = 0; j < q.length; j += 4) {
    const x = q[j]!;
    const y = q[j + 1]!;
    const z = q[j + 2]!;
    const w = q[j + 3]!;
    out.set([-z, w, x, -y], j);
  }
  return out;
}

/** A pose's positions and rotations in an engine's frame (a `Pose` or an `InterpolatedPose`). */
export function poseToEngine(
  pose: { readonly positions: ArrayLike<number>; readonly rotations?: ArrayLike<number> | undefined },
  engine: Engine,
): { positions: Float64Array; rotations?: Float64Array } {
  const positions = posToEngine(pose.positions, engine);
  return pose.rotations === undefined
    ? { positions }
    : { positions, rotations: quatToEngine(pose.rotations, engine) };
}

export const BONE_RIGS = ["unity", "vrm", "unreal", "unreal_ue4"] as const;
/**
 * `unity`: `HumanBodyBones` member names; `vrm`: VRM humanoid bone names (0.x and
 * 1.0); `unreal`: UE5 Manny/Quinn; `unreal_ue4`: UE4 SK_Mannequin (the same names
 * but the chest, spine_03 there, spine_05 in UE5). The rigs' extra bones (shoulders,
 * upper chest, further spine and neck bones) have no posecast joint: leave them at rest.
 */
export type BoneRig = (typeof BONE_RIGS)[number];

// joint: [Unity HumanBodyBones, VRM humanoid, UE5 Manny, UE4 Mannequin]
const BONE_TABLE: Readonly<Record<JointName, readonly [string, string, string, string]>> = {
  PELVIS: ["Hips", "hips", "pelvis", "pelvis"],
  SPINE: ["Spine", "spine", "spine_01", "spine_01"],
  CHEST: ["Chest", "chest", "spine_05", "spine_03"],
  NECK: ["Neck", "neck", "neck_01", "neck_01"],
  HEAD: ["Head", "head", "head", "head"],
  LEFT_UPPER_ARM: ["LeftUpperArm", "leftUpperArm", "upperarm_l", "upperarm_l"],
  LEFT_FOREARM: ["LeftLowerArm", "leftLowerArm", "lowerarm_l", "lowerarm_l"],
  LEFT_HAND: ["LeftHand", "leftHand", "hand_l", "hand_l"],
  RIGHT_UPPER_ARM: ["RightUpperArm", "rightUpperArm", "upperarm_r", "upperarm_r"],
  RIGHT_FOREARM: ["RightLowerArm", "rightLowerArm", "lowerarm_r", "lowerarm_r"],
  RIGHT_HAND: ["RightHand", "rightHand", "hand_r", "hand_r"],
  LEFT_THIGH: ["LeftUpperLeg", "leftUpperLeg", "thigh_l", "thigh_l"],
  LEFT_SHIN: ["LeftLowerLeg", "leftLowerLeg", "calf_l", "calf_l"],
  LEFT_FOOT: ["LeftFoot", "leftFoot", "foot_l", "foot_l"],
  LEFT_TOE: ["LeftToes", "leftToes", "ball_l", "ball_l"],
  RIGHT_THIGH: ["RightUpperLeg", "rightUpperLeg", "thigh_r", "thigh_r"],
  RIGHT_SHIN: ["RightLowerLeg", "rightLowerLeg", "calf_r", "calf_r"],
  RIGHT_FOOT: ["RightFoot", "rightFoot", "foot_r", "foot_r"],
  RIGHT_TOE: ["RightToes", "rightToes", "ball_r", "ball_r"],
};

/** Bone names by rig, in joint order: `BONES.unity[Joint.LEFT_FOREARM] === "LeftLowerArm"`. */
export const BONES: Readonly<Record<BoneRig, readonly string[]>> = {
  unity: JOINT_NAMES.map((j) => BONE_TABLE[j][0]),
  vrm: JOINT_NAMES.map((j) => BONE_TABLE[j][1]),
  unreal: JOINT_NAMES.map((j) => BONE_TABLE[j][2]),
  unreal_ue4: JOINT_NAMES.map((j) => BONE_TABLE[j][3]),
};

/** The bone of `rig` that `joint` drives. */
export function boneName(joint: JointName, rig: BoneRig): string {
  return BONE_TABLE[joint][BONE_RIGS.indexOf(rig)]!;
}
