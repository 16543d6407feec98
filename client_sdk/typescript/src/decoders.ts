/**
 * The decoders, one per message type (pure): a validated wire map in, a message out.
 * `codec.ts`'s {@link fromWire} picks one by `type` after its checks (size, root map,
 * depth, known type); each checks its own fields in spec order and throws the
 * {@link ProtocolError} subclass for the first rule broken. Mirrors the per-type code of
 * `posecast/online/protocol/wire.py`.
 *
 * `version` is the connection's protocol: v2 wants `version` 2 in `hello`, a `handle`
 * (the avatar id, `avatarId` in the messages) and `skeleton` for every `welcome` member
 * and presence `join`, and knows `pose_rate_hz` and `forecast_ms`.
 */

import {
  BadFieldError,
  OutOfRangeError,
  ProtocolError,
  VersionUnsupportedError,
} from "./errors.js";
import {
  asBin,
  asBool,
  asEnum,
  asFloat,
  asId,
  asInt,
  asList,
  asMap,
  asName,
  asPoint,
  asStr,
  asSites,
  asTrackers,
  CODE_PATTERN,
  has,
} from "./fields.js";
import {
  ALL_TRACKERS_VALID,
  type Bye,
  type Calibrate,
  type ErrorMessage,
  type Forecast,
  type Frame,
  type Hello,
  JOINT_NAMES,
  type Kick,
  LAYOUTS,
  LIMIT_RANGES,
  type Limits,
  MAX_FORECAST_MS,
  MAX_HEIGHT_M,
  MAX_ID_BYTES,
  MAX_LOOKAHEAD_FRAMES,
  MAX_TIME_S,
  type Member,
  type Message,
  MIN_HEIGHT_M,
  type Ping,
  type Pong,
  type Pose,
  type PoseRate,
  POSE_RATES_HZ,
  type Poses,
  PRESENCE_EVENTS,
  type Presence,
  PROTOCOL_V2,
  ROLES,
  SELECTOR_KINDS,
  type Selector,
  SKELETON_BYTES,
  type SkeletonMessage,
  UINT32_MAX,
  type Welcome,
} from "./messages.js";
import type { WireMap } from "./msgpack.js";
import { MAX_LAYOUT_BYTES, MAX_SITES, parseTrackerSet } from "./sites.js";
import { mm2pos, POS_BYTES, ROT_BYTES, snorm2quat } from "./quantize.js";

/** Validates the wire map of one message type on a connection speaking `version`. */
export type Decoder = (m: WireMap, lim: Limits, version: number) => Message;
type Mutable<T> = { -readonly [K in keyof T]: T[K] };
const T_RANGE = [0, MAX_TIME_S] as const;
const SELECTOR_FIELDS: Readonly<Record<string, readonly string[]>> = {
  anomaly: ["factor"],
  target: ["joint", "point", "margin_m"],
  obstacle: ["joint", "point", "radius_m"],
};

function text(m: WireMap, key: string, lim: Limits): string | undefined {
  return has(m, key) ? asStr(m, key, lim.max_text_bytes, 0) : undefined;
}

function optFloat(m: WireMap, key: string, lo: number, hi: number): number | undefined {
  return has(m, key) ? asFloat(m, key, lo, hi) : undefined;
}

/** Copy the defined entries of `fields` onto `base` (exactOptionalPropertyTypes-safe). */
function withOptional<T>(base: T, fields: Record<string, unknown>): T {
  const out: Record<string, unknown> = { ...(base as Record<string, unknown>) };
  for (const [k, v] of Object.entries(fields)) if (v !== undefined) out[k] = v;
  return out as T;
}

/** v2: a pose rate, one of 60, 30, 20, 15 Hz (another number is OUT_OF_RANGE). */
function asPoseRate(m: WireMap, key: string): number {
  const rate = asFloat(m, key, 0, 1000);
  if (!(POSE_RATES_HZ as readonly number[]).includes(rate)) {
    throw new OutOfRangeError(`${key}=${rate}: not 60, 30, 20 or 15`, { field: key });
  }
  return rate;
}

/** v2: a forecast horizon, 0 to 100 ms (else OUT_OF_RANGE). */
function asForecast(m: WireMap, key: string): number {
  return asFloat(m, key, 0, MAX_FORECAST_MS);
}

function withRefSeq(err: unknown, seq: number): unknown {
  if (!(err instanceof ProtocolError)) return err;
  const cls = err.constructor as typeof ProtocolError;
  return new cls(err.message, { field: err.field, refSeq: seq, fatal: err.fatal }, err.code);
}

function decodeHello(m: WireMap, lim: Limits, connection: number): Hello {
  const version = m.get("version");
  if (typeof version !== "number") {
    throw new BadFieldError("field version must be an integer", { field: "version" });
  }
  if (version !== connection) {
    throw new VersionUnsupportedError(
      `version ${version} on a posecast.v${connection} connection`,
      { field: "version" },
    );
  }
  let watch: string[] | undefined;
  if (has(m, "watch")) {
    watch = asList(m, "watch", lim.max_watch_rooms).map((v, i) =>
      asId(new Map([[`watch[${i}]`, v]]), `watch[${i}]`, lim.max_room_bytes),
    );
  }
  return withOptional<Hello>(
    {
      type: "hello",
      version,
      token: asStr(m, "token", lim.max_token_bytes, 0),
      room: asId(m, "room", lim.max_room_bytes),
      name: asName(m, "name", lim.max_name_bytes),
    },
    {
      layout: has(m, "layout") ? asLayout(m) : undefined,
      rate_hz: optFloat(m, "rate_hz", 1, lim.max_rate_hz),
      watch: watch !== undefined && watch.length > 0 ? watch : undefined,
      pose_rate_hz:
        connection >= PROTOCOL_V2 && has(m, "pose_rate_hz") ? asPoseRate(m, "pose_rate_hz") : undefined,
      forecast_ms:
        connection >= PROTOCOL_V2 && has(m, "forecast_ms") ? asForecast(m, "forecast_ms") : undefined,
    },
  );
}

/** hello.layout: a named layout or a tracker set (BAD_FIELD saying why not). */
function asLayout(m: WireMap): string {
  const text = asStr(m, "layout", MAX_LAYOUT_BYTES);
  if ((LAYOUTS as readonly string[]).includes(text)) return text;
  try {
    parseTrackerSet(text);
  } catch (err) {
    const why = err instanceof Error ? err.message : String(err);
    throw new BadFieldError(
      `layout '${text}': ${why} (a named layout: ${LAYOUTS.join(", ")}, or a tracker set)`,
      { field: "layout" },
    );
  }
  return text;
}

function decodeWelcome(m: WireMap, lim: Limits, connection: number): Welcome {
  const members: Member[] = asList(m, "members", lim.max_players).map((item, i) => {
    if (!(item instanceof Map)) {
      throw new BadFieldError(`members[${i}]: expected a map`, { field: `members[${i}]` });
    }
    const at = `members[${i}].`;
    const player = asId(item, "player", MAX_ID_BYTES, at);
    const name = asName(item, "name", lim.max_name_bytes, at);
    if (connection < PROTOCOL_V2) return { player, name };
    return {
      player,
      name,
      avatarId: asInt(item, "handle", 0, UINT32_MAX, at), // "handle": the avatar id's wire key
      skeleton: asBin(item, "skeleton", SKELETON_BYTES, at),
    };
  });
  const lm = asMap(m, "limits");
  const limits: Partial<Mutable<Limits>> = {};
  for (const [k, [lo, hi]] of Object.entries(LIMIT_RANGES)) {
    limits[k as keyof Limits] = asInt(lm, k, lo, hi, "limits.");
  }
  const welcome: Welcome = {
    type: "welcome",
    version: asInt(m, "version", 1, 255),
    player: asId(m, "player", MAX_ID_BYTES),
    session: asId(m, "session", MAX_ID_BYTES),
    role: asEnum(m, "role", ROLES),
    room: asId(m, "room", lim.max_room_bytes),
    t: asFloat(m, "t", ...T_RANGE),
    rate_hz: asFloat(m, "rate_hz", 1, 1000),
    lookahead_frames: asInt(m, "lookahead_frames", 0, MAX_LOOKAHEAD_FRAMES),
    members,
    limits: limits as Limits,
  };
  if (connection < PROTOCOL_V2) return welcome;
  return withOptional<Welcome>(
    { ...welcome, pose_rate_hz: asPoseRate(m, "pose_rate_hz") },
    { forecast_ms: has(m, "forecast_ms") ? asForecast(m, "forecast_ms") : undefined },
  );
}

function decodeCalibrate(m: WireMap): Calibrate {
  const hasHeight = has(m, "height_m");
  const hasTpose = has(m, "tpose");
  if (hasTpose && !asBool(m, "tpose")) {
    throw new BadFieldError("tpose, when present, must be true", { field: "tpose" });
  }
  if (hasHeight && hasTpose) {
    throw new BadFieldError("give height_m or tpose, not both", { field: "tpose" });
  }
  if (hasHeight) {
    return { type: "calibrate", height_m: asFloat(m, "height_m", MIN_HEIGHT_M, MAX_HEIGHT_M) };
  }
  if (!hasTpose) {
    throw new BadFieldError("calibrate needs height_m or tpose: true", { field: "height_m" });
  }
  if (has(m, "sites")) {
    if (has(m, "trackers")) throw new BadFieldError("give trackers or sites, not both", { field: "sites" });
    return { type: "calibrate", tpose: true, sites: asSites(m, "sites", MAX_SITES).rows };
  }
  return { type: "calibrate", tpose: true, trackers: asTrackers(m, "trackers") };
}

function decodeFrame(m: WireMap): Frame {
  const seq = asInt(m, "seq", 0, UINT32_MAX);
  try {
    const t = asFloat(m, "t", ...T_RANGE);
    if (has(m, "sites")) {
      if (has(m, "trackers")) throw new BadFieldError("give trackers or sites, not both", { field: "sites" });
      const mask = has(m, "valid") ? asInt(m, "valid", 0, 2 ** MAX_SITES - 1) : undefined;
      const { rows, valid } = asSites(m, "sites", MAX_SITES, mask);
      return withOptional<Frame>(
        { type: "frame", seq, t, sites: rows },
        { valid: valid === 2 ** rows.length - 1 ? undefined : valid },
      );
    }
    const valid = has(m, "valid") ? asInt(m, "valid", 0, ALL_TRACKERS_VALID) : ALL_TRACKERS_VALID;
    const trackers = asTrackers(m, "trackers", valid);
    return withOptional<Frame>(
      { type: "frame", seq, t, trackers },
      { valid: valid === ALL_TRACKERS_VALID ? undefined : valid },
    );
  } catch (err) {
    throw withRefSeq(err, seq);
  }
}

function decodePose(m: WireMap): Pose {
  const root = asPoint(m, "root");
  const rot = has(m, "rot") ? asBin(m, "rot", ROT_BYTES) : undefined;
  return withOptional<Pose>(
    {
      type: "pose",
      player: asId(m, "player", MAX_ID_BYTES),
      seq: asInt(m, "seq", 0, UINT32_MAX),
      t: asFloat(m, "t", ...T_RANGE),
      positions: mm2pos(root, asBin(m, "pos_mm", POS_BYTES)),
    },
    { rotations: rot === undefined ? undefined : snorm2quat(rot) },
  );
}

function decodePresence(m: WireMap, lim: Limits, connection: number): Presence {
  const presence: Presence = {
    type: "presence",
    event: asEnum(m, "event", PRESENCE_EVENTS),
    room: asId(m, "room", lim.max_room_bytes),
    player: asId(m, "player", MAX_ID_BYTES),
    name: asName(m, "name", lim.max_name_bytes),
  };
  if (connection < PROTOCOL_V2 || presence.event !== "join") return presence;
  return {
    ...presence,
    avatarId: asInt(m, "handle", 0, UINT32_MAX), // "handle": the avatar id's wire key
    skeleton: asBin(m, "skeleton", SKELETON_BYTES),
  };
}

function decodePoses(m: WireMap): Poses {
  const t = asFloat(m, "t", ...T_RANGE);
  if (!has(m, "data")) throw new BadFieldError("missing field data", { field: "data" });
  const data = m.get("data");
  if (!(data instanceof Uint8Array)) {
    throw new BadFieldError("data: expected a bin", { field: "data" });
  }
  return { type: "poses", t, data };
}

function decodeSelector(m: WireMap): Selector {
  const player = asId(m, "player", MAX_ID_BYTES);
  const kind = asEnum(m, "kind", SELECTOR_KINDS);
  for (const key of ["joint", "point", "radius_m", "margin_m", "factor"]) {
    if (has(m, key) && !SELECTOR_FIELDS[kind]!.includes(key)) {
      throw new BadFieldError(`${key} does not apply to a ${kind} selector`, { field: key });
    }
  }
  const aimed = kind !== "anomaly";
  return withOptional<Selector>(
    { type: "selector", player, kind },
    {
      joint: aimed ? asEnum(m, "joint", JOINT_NAMES) : undefined,
      point: aimed ? asPoint(m, "point") : undefined,
      radius_m: optFloat(m, "radius_m", 0.001, 10),
      margin_m: optFloat(m, "margin_m", 0, 10),
      factor: optFloat(m, "factor", 0.1, 100),
    },
  );
}

function decodeError(m: WireMap, lim: Limits): ErrorMessage {
  const code = asStr(m, "code", 32);
  if (!CODE_PATTERN.test(code)) {
    throw new BadFieldError("code must be upper-case letters, digits and _", { field: "code" });
  }
  return withOptional<ErrorMessage>(
    {
      type: "error",
      code,
      message: asStr(m, "message", lim.max_text_bytes, 0),
      fatal: asBool(m, "fatal"),
    },
    {
      field: text(m, "field", lim),
      ref_seq: has(m, "ref_seq") ? asInt(m, "ref_seq", 0, UINT32_MAX) : undefined,
    },
  );
}

/** The decoder of each message type, in spec order (v1 and v2 types alike). */
export const DECODERS: Readonly<Record<string, Decoder>> = {
  hello: decodeHello,
  welcome: decodeWelcome,
  calibrate: decodeCalibrate,
  frame: decodeFrame,
  pose: decodePose,
  presence: decodePresence,
  selector: decodeSelector,
  kick: (m, lim): Kick =>
    withOptional<Kick>(
      { type: "kick", player: asId(m, "player", MAX_ID_BYTES) },
      { reason: text(m, "reason", lim) },
    ),
  ping: (m): Ping => ({ type: "ping", t0: asFloat(m, "t0", ...T_RANGE) }),
  pong: (m): Pong => ({
    type: "pong",
    t0: asFloat(m, "t0", ...T_RANGE),
    t1: asFloat(m, "t1", ...T_RANGE),
    t2: asFloat(m, "t2", ...T_RANGE),
  }),
  error: decodeError,
  bye: (m, lim): Bye => withOptional<Bye>({ type: "bye" }, { reason: text(m, "reason", lim) }),
  poses: decodePoses,
  skeleton: (m): SkeletonMessage => ({
    type: "skeleton",
    player: asId(m, "player", MAX_ID_BYTES),
    avatarId: asInt(m, "handle", 0, UINT32_MAX), // "handle": the avatar id's wire key
    skeleton: asBin(m, "skeleton", SKELETON_BYTES),
  }),
  pose_rate: (m): PoseRate => ({ type: "pose_rate", rate_hz: asPoseRate(m, "rate_hz") }),
  resync: () => ({ type: "resync" }),
  forecast: (m): Forecast => ({ type: "forecast", ms: asForecast(m, "ms") }),
};
