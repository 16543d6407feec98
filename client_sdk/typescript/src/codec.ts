/**
 * Bytes <-> messages for protocols v1 and v2. Pure functions: no sockets, no clocks, no state.
 *
 * {@link encode} writes the canonical bytes (`proto/README.md`, "Canonical encoding"):
 * a msgpack map, `type` first and then the fields in spec order, absent optionals
 * left out, every float field as float64, everything else in its smallest form.
 *
 * {@link decode} accepts every valid encoding and checks, in the spec's order: size
 * (TOO_LARGE), msgpack syntax and structural bounds (MALFORMED / TOO_LARGE), that the
 * root is a map, nesting depth (MALFORMED), `type` (BAD_FIELD / UNKNOWN_TYPE), then
 * the fields of that type. The per-type code mirrors `posecast/online/protocol/wire.py`.
 *
 * `version` (in {@link DecodeOptions}) is the connection's protocol, the subprotocol the
 * server selected: v2 knows `poses`, `skeleton`, `pose_rate`, `resync` and `forecast` but
 * no `pose`, wants `version` 2 in `hello`, a `handle` (the avatar id, `avatarId` in the
 * messages) and `skeleton` for every `welcome` member and presence `join`, and lets a
 * server message (and its `poses.data` bin) reach 16384 bytes. `poses.data` is opaque
 * here: `records.ts` reads it against the client's state.
 * {@link encode} writes whatever fields a message has, so it serves both versions.
 *
 * The per-type halves: `decoders.ts` (one decoder per type) and `encoders.ts` (one
 * canonical wire map per type); the field readers they share, `fields.ts`.
 */

import { DECODERS } from "./decoders.js";
import { BadFieldError, MalformedError, TooLargeError, UnknownTypeError } from "./errors.js";
import { toWire } from "./encoders.js";
import {
  DEFAULT_LIMITS,
  type Limits,
  MAX_SERVER_MESSAGE_BYTES_V2,
  type Message,
  PROTOCOL_V2,
  PROTOCOL_VERSION,
} from "./messages.js";
import { pack, unpack, type WireMap } from "./msgpack.js";

export { toWire } from "./encoders.js";

export interface DecodeOptions {
  /** The limits in force; before a `welcome`, the v1 defaults. */
  limits?: Limits;
  /** A tighter size cap than the version's bound. */
  maxBytes?: number;
  /** The connection's protocol, 1 (the default) or 2. */
  version?: number;
}

/** The types a v2 client may send: they stay within `max_message_bytes` in v2 too. */
const CLIENT_TYPES: ReadonlySet<string> = new Set([
  "hello",
  "calibrate",
  "frame",
  "selector",
  "kick",
  "ping",
  "bye",
  "pose_rate",
  "resync",
  "forecast",
]);
const V2_ONLY_TYPES: ReadonlySet<string> = new Set(["poses", "skeleton", "pose_rate", "resync", "forecast"]);

/** The canonical bytes of `msg`. */
export function encode(msg: Message): Uint8Array {
  return pack(toWire(msg));
}

/**
 * Parse and validate one WebSocket message.
 *
 * @throws ProtocolError the subclass for the first rule broken, with `field` (and
 *   `refSeq` for a frame whose `seq` was readable) set where they apply.
 */
export function decode(data: Uint8Array, options: DecodeOptions = {}): Message {
  const limits = options.limits ?? DEFAULT_LIMITS;
  const version = options.version ?? PROTOCOL_VERSION;
  const v2 = version >= PROTOCOL_V2;
  const top = v2 ? MAX_SERVER_MESSAGE_BYTES_V2 : limits.max_message_bytes;
  const cap = Math.min(options.maxBytes ?? Infinity, top);
  if (data.length > cap) throw new TooLargeError(`message of ${data.length} bytes, limit ${cap}`);
  const { value, tooDeep } = v2 ? unpack(data, cap) : unpack(data);
  if (!(value instanceof Map)) throw new MalformedError("a message is a msgpack map");
  if (tooDeep) throw new MalformedError("nested deeper than 8 maps and arrays");
  return fromWire(value, limits, version, data.length);
}

/**
 * Validate an unpacked wire map into a message (the second half of {@link decode}).
 * `size` is the message's length in bytes, for v2's client-message cap.
 */
export function fromWire(
  m: WireMap,
  limits: Limits = DEFAULT_LIMITS,
  version: number = PROTOCOL_VERSION,
  size = 0,
): Message {
  const kind = m.get("type");
  if (typeof kind !== "string") {
    throw new BadFieldError("missing or non-string field type", { field: "type" });
  }
  const v2 = version >= PROTOCOL_V2;
  const known = v2 ? kind !== "pose" : !V2_ONLY_TYPES.has(kind);
  const decoder = known && Object.hasOwn(DECODERS, kind) ? DECODERS[kind] : undefined;
  if (decoder === undefined) {
    throw new UnknownTypeError(`unknown message type ${JSON.stringify(kind.slice(0, 40))}`, {
      field: "type",
    });
  }
  if (v2 && CLIENT_TYPES.has(kind) && size > limits.max_message_bytes) {
    throw new TooLargeError(`a ${kind} message of ${size} bytes`);
  }
  return decoder(m, limits, version);
}

/** Every message type of v1 and v2, in spec order. */
export const ALL_MESSAGE_TYPES: readonly string[] = Object.keys(DECODERS);
/** The v1 message types, in spec order. */
export const MESSAGE_TYPES: readonly string[] = ALL_MESSAGE_TYPES.filter((k) => !V2_ONLY_TYPES.has(k));
/** The v2 message types (no `pose`), in spec order. */
export const MESSAGE_TYPES_V2: readonly string[] = ALL_MESSAGE_TYPES.filter((k) => k !== "pose");
