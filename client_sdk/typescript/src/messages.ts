/**
 * The v1 and v2 wire messages as typed values, with the protocol's constants and limits.
 *
 * One interface per message `type`. Field names are the wire names (`rate_hz`,
 * `ref_seq`, ...), so this file reads side by side with `proto/README.md`, which is
 * the spec; the client API around it (`PosecastClient`) uses camelCase. One field is
 * not named as on the wire: `avatarId`, the avatar id, whose wire key is `handle`.
 *
 * v2 (`posecast.v2`) adds `poses`, `skeleton`, `pose_rate`, `resync` and `forecast`, an
 * `avatarId` and `skeleton` on welcome members and presence joins, and `pose_rate_hz` and
 * `forecast_ms` in hello and welcome; it has no `pose` on the wire (the client rebuilds {@link Pose}s from records).
 *
 * Units everywhere: metres, seconds, a right-handed world with +Y up, a character
 * facing +Z, quaternions xyzw (scalar last).
 */

/** The default version of {@link decode}'s `version` option (v1). */
export const PROTOCOL_VERSION = 1;
export const PROTOCOL_V1 = 1;
export const PROTOCOL_V2 = 2;
/** The WebSocket subprotocol a v1 client offers. */
export const SUBPROTOCOL = "posecast.v1";
export const SUBPROTOCOL_V2 = "posecast.v2";
/** The subprotocol of each version. */
export const SUBPROTOCOLS: Readonly<Record<number, string>> = { 1: SUBPROTOCOL, 2: SUBPROTOCOL_V2 };
/** v2: the pose rates a client may ask for (divisors of the 60 Hz tick), Hz. */
export const POSE_RATES_HZ = [60, 30, 20, 15] as const;
/** v2: the furthest ahead a client may ask its poses to be forecast, ms. */
export const MAX_FORECAST_MS = 100;
/** v2: a server message (and so `poses.data`) may be up to this many bytes. */
export const MAX_SERVER_MESSAGE_BYTES_V2 = 16384;
/** v2: a skeleton bin, 18 x 3 int16 LE in 0.1 mm (bone offsets SPINE ... RIGHT_TOE). */
export const SKELETON_BYTES = 108;

export const LAYOUTS = ["hmd3+waist", "hmd3"] as const;
/**
 * `hmd3+waist`: head, both hands and waist (the 4-point model). `hmd3`: head and both
 * hands only (the headset-only model; a WebXR session without a waist tracker).
 */
export type Layout = (typeof LAYOUTS)[number];
export const ROLES = ["player", "spectator", "backend"] as const;
export type Role = (typeof ROLES)[number];
export const PRESENCE_EVENTS = ["join", "leave", "stale", "active"] as const;
export type PresenceEvent = (typeof PRESENCE_EVENTS)[number];
export const SELECTOR_KINDS = ["anomaly", "target", "obstacle"] as const;
export type SelectorKind = (typeof SELECTOR_KINDS)[number];

export const MAX_COORD_M = 1000; // |x|, |y|, |z| of any position on the wire
export const QUAT_TOLERANCE = 1e-3; // | |q| - 1 | above this is NOT_NORMALISED
export const MIN_HEIGHT_M = 0.9;
export const MAX_HEIGHT_M = 2.5;
export const ALL_TRACKERS_VALID = 0b1111;
export const UINT32_MAX = 2 ** 32 - 1;
export const MAX_TIME_S = 1e12;
export const MAX_ID_BYTES = 64;
export const MAX_LOOKAHEAD_FRAMES = 255;

/** Tracker slots, in wire order (`server/posecast/tracking/features.py`). */
export const TRACKER_SLOTS = ["HEAD", "LEFT_HAND", "RIGHT_HAND", "WAIST"] as const;
export type TrackerSlot = (typeof TRACKER_SLOTS)[number];
export const NUM_TRACKERS = 4;

/**
 * The 19 joints in wire order (`server/posecast/skeleton.py`); parents come before
 * children. A joint is named by this string on the wire, never by its index.
 */
export const JOINT_NAMES = [
  "PELVIS",
  "SPINE",
  "CHEST",
  "NECK",
  "HEAD",
  "LEFT_UPPER_ARM",
  "LEFT_FOREARM",
  "LEFT_HAND",
  "RIGHT_UPPER_ARM",
  "RIGHT_FOREARM",
  "RIGHT_HAND",
  "LEFT_THIGH",
  "LEFT_SHIN",
  "LEFT_FOOT",
  "LEFT_TOE",
  "RIGHT_THIGH",
  "RIGHT_SHIN",
  "RIGHT_FOOT",
  "RIGHT_TOE",
] as const;
export type JointName = (typeof JOINT_NAMES)[number];
export const NUM_JOINTS = 19;
/** Index of each joint in {@link JOINT_NAMES} (and in a pose's arrays). */
export const Joint: Readonly<Record<JointName, number>> = Object.freeze(
  Object.fromEntries(JOINT_NAMES.map((n, i) => [n, i])) as Record<JointName, number>,
);
/** Parent index per joint, -1 for the root: bones are `(PARENTS[j], j)` for j >= 1. */
export const PARENTS: readonly number[] = [
  -1, 0, 1, 2, 3, 2, 5, 6, 2, 8, 9, 0, 11, 12, 13, 0, 15, 16, 17,
];

/** Protocol limits; the defaults are the v1 maxima, and a server may lower them. */
export interface Limits {
  readonly max_message_bytes: number;
  readonly max_rate_hz: number;
  readonly max_players: number;
  readonly max_name_bytes: number;
  readonly max_room_bytes: number;
  readonly max_token_bytes: number;
  readonly max_text_bytes: number;
  readonly max_watch_rooms: number;
}

/** `[floor, v1 max]` of each limit, in canonical key order. */
export const LIMIT_RANGES: Readonly<Record<keyof Limits, readonly [number, number]>> = {
  max_message_bytes: [1024, 8192],
  max_rate_hz: [1, 120],
  max_players: [1, 32],
  max_name_bytes: [1, 64],
  max_room_bytes: [1, 64],
  max_token_bytes: [0, 4096],
  max_text_bytes: [64, 512],
  max_watch_rooms: [0, 16],
};

/** What a client assumes until its `welcome` says otherwise. */
export const DEFAULT_LIMITS: Limits = Object.freeze({
  max_message_bytes: 8192,
  max_rate_hz: 120,
  max_players: 32,
  max_name_bytes: 64,
  max_room_bytes: 64,
  max_token_bytes: 4096,
  max_text_bytes: 512,
  max_watch_rooms: 16,
});

/** One tracker on the wire: `[px, py, pz, qx, qy, qz, qw]`, metres and xyzw. */
export type Tracker = readonly [number, number, number, number, number, number, number];
/** The 4 trackers of a frame, in slot order HEAD, LEFT_HAND, RIGHT_HAND, WAIST. */
export type Trackers = readonly [Tracker, Tracker, Tracker, Tracker];

export interface Hello {
  readonly type: "hello";
  readonly version: number;
  readonly token: string;
  readonly room: string;
  readonly name: string;
  /** A {@link Layout} or a tracker set (`sites.ts`). Absent: the server takes `hmd3+waist`. */
  readonly layout?: Layout | string;
  /** Frames per second the client will send; absent: 60. */
  readonly rate_hz?: number;
  /** Backends only: further rooms to watch. Empty is written as absent. */
  readonly watch?: readonly string[];
  /** v2: poses per second wanted (60, 30, 20 or 15); absent: 60. */
  readonly pose_rate_hz?: number;
  /** v2: poses forecast this many ms ahead, 0 to 100; absent: 0 (none). */
  readonly forecast_ms?: number;
}

export interface Member {
  readonly player: string;
  readonly name: string;
  /** v2 (required there): the avatar id, how pose records name this player on this
   * connection (`handle` on the wire). */
  readonly avatarId?: number;
  /** v2 (required there): the player's bone offsets, {@link SKELETON_BYTES} bytes. */
  readonly skeleton?: Uint8Array;
}

export interface Welcome {
  readonly type: "welcome";
  readonly version: number;
  /** This connection's id (spectators and backends get one too). */
  readonly player: string;
  readonly session: string;
  readonly role: Role;
  readonly room: string;
  /** Server time at send, seconds. */
  readonly t: number;
  /** The room's pose rate, Hz. */
  readonly rate_hz: number;
  /** A pose lags its source frame by this many frames. */
  readonly lookahead_frames: number;
  readonly members: readonly Member[];
  readonly limits: Limits;
  /** v2 (required there): the poses per second this client gets. */
  readonly pose_rate_hz?: number;
  /** v2: present when this client asked for a forecast: how far ahead its poses are (whole ticks). */
  readonly forecast_ms?: number;
}

export type Calibrate =
  | { readonly type: "calibrate"; readonly height_m: number }
  | { readonly type: "calibrate"; readonly tpose: true; readonly trackers: Trackers }
  /** A tracker set's T-pose: one row per site, in the set's order. */
  | { readonly type: "calibrate"; readonly tpose: true; readonly sites: readonly Tracker[] };

interface FrameBase {
  readonly type: "frame";
  /** uint32, +1 per frame, wraps. */
  readonly seq: number;
  /** Client monotonic time when the trackers were sampled, seconds. */
  readonly t: number;
  /** Bit i set: slot (site row) i is tracked. Absent means all. */
  readonly valid?: number;
}

/** A frame of the four tracker slots, or of a tracker set's 1 to 10 `sites` rows (a
 * positional site's position in metres, an inertial one's acceleration in m/s^2). */
export type Frame =
  | (FrameBase & { readonly trackers: Trackers })
  | (FrameBase & { readonly sites: readonly Tracker[] });

export interface Pose {
  readonly type: "pose";
  readonly player: string;
  /** `seq` of the source frame. */
  readonly seq: number;
  /** Server time of the tick that produced it, seconds. */
  readonly t: number;
  /** World positions, metres: 19 joints x xyz, joint order (length 57). */
  readonly positions: Float64Array;
  /** World rotations, xyzw: 19 joints x 4 (length 76), when the server sends them (always in v2). */
  readonly rotations?: Float64Array;
  /**
   * v2: the record's items, xyzw, 19 x 4: PELVIS's world rotation, then each joint's
   * rotation relative to its parent (`world[j] = world[parent[j]] * local[j]`).
   */
  readonly localRotations?: Float64Array;
  /** v2: the record was a keyframe (a clean snap point for interpolation). */
  readonly keyframe?: boolean;
  /** v2: the upper-body pass left the head or a hand more than 1 mm from its tracker. */
  readonly reachLimited?: boolean;
}

export interface Presence {
  readonly type: "presence";
  readonly event: PresenceEvent;
  readonly room: string;
  readonly player: string;
  readonly name: string;
  /** v2 `join` (required there): the player's avatar id on this connection (`handle` on the wire). */
  readonly avatarId?: number;
  /** v2 `join` (required there): its bone offsets, {@link SKELETON_BYTES} bytes. */
  readonly skeleton?: Uint8Array;
}

/** v2, server to client: all of a tick's pose records for this client. */
export interface Poses {
  readonly type: "poses";
  /** Server time of the newest tick whose poses it carries, seconds. */
  readonly t: number;
  /** The pose records (`records.ts` reads them). */
  readonly data: Uint8Array;
}

/** v2, server to client: a player's calibration changed its bone offsets. */
export interface SkeletonMessage {
  readonly type: "skeleton";
  readonly player: string;
  /** The player's avatar id on this connection (`handle` on the wire). */
  readonly avatarId: number;
  readonly skeleton: Uint8Array;
}

/** v2, client to server: poses at this rate from now on (60, 30, 20 or 15 Hz). */
export interface PoseRate {
  readonly type: "pose_rate";
  readonly rate_hz: number;
}

/**
 * v2, client to server: poses forecast `ms` (0 to 100) ahead from now on, 0 for none; the
 * server rounds it to whole ticks and stamps each `poses.t` that far past its tick.
 */
export interface Forecast {
  readonly type: "forecast";
  readonly ms: number;
}

/** v2, client to server: a keyframe of every avatar with the next `poses`. */
export interface Resync {
  readonly type: "resync";
}

export interface Selector {
  readonly type: "selector";
  readonly player: string;
  readonly kind: SelectorKind;
  readonly joint?: JointName;
  readonly point?: readonly [number, number, number];
  readonly radius_m?: number;
  readonly margin_m?: number;
  readonly factor?: number;
}

export interface Kick {
  readonly type: "kick";
  readonly player: string;
  readonly reason?: string;
}

export interface Ping {
  readonly type: "ping";
  /** Client time at send, seconds. */
  readonly t0: number;
}

export interface Pong {
  readonly type: "pong";
  readonly t0: number;
  readonly t1: number;
  readonly t2: number;
}

/** The wire `error` message (the thrown kind is `ProtocolError`). */
export interface ErrorMessage {
  readonly type: "error";
  readonly code: string;
  readonly message: string;
  readonly fatal: boolean;
  readonly field?: string;
  readonly ref_seq?: number;
}

export interface Bye {
  readonly type: "bye";
  readonly reason?: string;
}

export type Message =
  | Hello
  | Welcome
  | Calibrate
  | Frame
  | Pose
  | Presence
  | Selector
  | Kick
  | Ping
  | Pong
  | ErrorMessage
  | Bye
  | Poses
  | SkeletonMessage
  | PoseRate
  | Resync
  | Forecast;

export type MessageType = Message["type"];

/** The `seq` after `seq` (uint32, wraps from 2**32 - 1 to 0). */
export function seqNext(seq: number): number {
  return seq >= UINT32_MAX ? 0 : seq + 1;
}

/** `newer - older` in serial-number arithmetic (RFC 1982), in `[-2**31, 2**31)`. */
export function seqDelta(newer: number, older: number): number {
  const d = (((newer - older) % 2 ** 32) + 2 ** 32) % 2 ** 32;
  return d >= 2 ** 31 ? d - 2 ** 32 : d;
}
