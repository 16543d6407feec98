/**
 * `@posecast/client`: stream VR tracker frames to a posecast server and receive every
 * player's full-body pose (wire protocol v2, falling back to v1; `proto/README.md`).
 * Browser and Node.
 *
 * - {@link connect} / {@link PosecastClient}: join, send frames, read events, reconnect.
 * - {@link fromXRFrame}: a WebXR frame as posecast trackers.
 * - {@link parseTrackerSet}, {@link toSites}: tracker sets (3 to 10 sites, positional or IMU).
 * - {@link encode} / {@link decode}: the canonical codec, for tools and tests.
 * - {@link decodeRecords}, {@link fk}: v2 pose records against an avatar's state; FK.
 * - Errors: one class per wire code ({@link ProtocolError} and subclasses).
 * - {@link Interpolator} / {@link PoseBuffer}: a jitter buffer, poses at any display rate,
 *   its render delay adapting to the measured jitter ({@link RenderDelay}).
 * - {@link poseToEngine}, {@link BONES}: Unity, Unreal and three.js frames; bone names.
 */

export {
  connect,
  PosecastClient,
  type ClientState,
  type ConnectOptions,
  type JoinOptions,
  type ReconnectOptions,
  type TokenSource,
  type WebSocketConstructor,
  type WebSocketLike,
} from "./client.js";
export { ClockSync, type ClockSample } from "./clock.js";
export {
  ALL_MESSAGE_TYPES,
  decode,
  encode,
  fromWire,
  MESSAGE_TYPES,
  MESSAGE_TYPES_V2,
  toWire,
  type DecodeOptions,
} from "./codec.js";
export {
  decodeRecords,
  fk,
  items2world,
  rootMetres,
  skeleton2offsets,
  type AvatarState,
  type DecodedRecord,
} from "./records.js";
export * from "./errors.js";
export type { ClientEvent, ErrorEvent, ReconnectingEvent, WelcomeEvent } from "./events.js";
export * from "./messages.js";
export { Float64, pack, unpack, type Wire, type WireMap } from "./msgpack.js";
export {
  jointPosition,
  jointRotation,
  toTrackers,
  type FrameInput,
  type TrackerPose,
} from "./trackers.js";
export {
  INERTIAL_SUFFIX,
  MAX_LAYOUT_BYTES,
  MAX_SITES,
  parseTrackerSet,
  SITE_JOINTS,
  SITE_KEYS,
  SITES,
  toSites,
  trackerSetOf,
  type ImuReading,
  type Site,
  type SitesInput,
  type TrackerSet,
} from "./sites.js";
export {
  fromXRFrame,
  xrToPosecast,
  type BodySiteKey,
  type FromXRFrameOptions,
  type XRFrameLike,
  type XRInputSourceLike,
  type XRPoseLike,
  type XRFrameInput,
  type XRRigidTransformLike,
} from "./webxr.js";
export {
  BONE_RIGS,
  BONES,
  boneName,
  ENGINE_FRAMES,
  ENGINES,
  engineToPos,
  engineToQuat,
  headToXRView,
  poseToEngine,
  posToEngine,
  quatToEngine,
  type BoneRig,
  type Engine,
  type EngineFrame,
} from "./conventions.js";
export {
  Interpolator,
  PoseBuffer,
  PoseSample,
  quatSlerp,
  type InterpOptions,
  type InterpolatedPose,
  type PoseInput,
  type SampleMode,
} from "./interp.js";
export { nearestRank, RenderDelay, type RenderDelayOptions } from "./render-delay.js";
