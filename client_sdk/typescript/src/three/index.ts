/**
 * `@posecast/client/three`: posecast avatars in three.js (a separate entry point, so the
 * core SDK stays free of dependencies). Peer dependencies: `three`, and
 * `@pixiv/three-vrm` for VRM models (only its loader is needed, by the caller).
 *
 * - {@link HumanoidAvatar}: a VRM ({@link humanoidFromVRM}) or a glTF humanoid
 *   ({@link humanoidFromGLTF}) fitted to a player's skeleton and driven by its poses.
 * - {@link AvatarRoom}: one avatar per player, added and removed on presence.
 * - The rest-pose helpers the fit uses: {@link REST_POSITIONS_M}, {@link restPositions},
 *   {@link bodyScale}, {@link hipsHeight}, {@link offsetsFromPose}.
 */

export { HumanoidAvatar, humanoidFromGLTF, humanoidFromVRM, type Humanoid, type VRMLike } from "./avatar.js";
export { AvatarRoom, type AvatarRoomOptions, type PoseLike } from "./room.js";
export {
  bodyScale,
  boneSum,
  hipsHeight,
  offsetsFromPose,
  REFERENCE_BONE_SUM_M,
  REFERENCE_OFFSETS_FLAT_M,
  REFERENCE_OFFSETS_M,
  REST_POSITIONS_M,
  restPositions,
} from "../rest.js";
