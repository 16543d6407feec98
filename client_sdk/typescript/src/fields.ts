/**
 * Field validators for the decoder: one msgpack value in, a checked value out
 * (the TypeScript twin of `posecast/online/protocol/fields.py`).
 *
 * Each takes the message map, the key, the value's bounds and `at` (a path prefix for
 * nested maps such as `members[3].`), and throws the error the spec names: BAD_FIELD
 * for a missing field or a wrong type, shape or value; OUT_OF_RANGE for a number
 * outside its range (NaN and infinities included) or a string of the wrong byte
 * length; NOT_NORMALISED for a quaternion off unit length. nil reads as absent.
 */

import { BadFieldError, NotNormalisedError, OutOfRangeError } from "./errors.js";
import {
  ALL_TRACKERS_VALID,
  MAX_COORD_M,
  NUM_TRACKERS,
  QUAT_TOLERANCE,
  type Tracker,
  type Trackers,
} from "./messages.js";
import { Float64, type Wire, type WireMap, utf8Length } from "./msgpack.js";

export const ID_PATTERN = /^[A-Za-z0-9_.:-]+$/; // rooms, player and session ids
export const CODE_PATTERN = /^[A-Z][A-Z0-9_]{0,31}$/; // error codes
// eslint-disable-next-line no-control-regex
const CONTROL = /[\u0000-\u001f\u007f]/; // not allowed in display names
const TRACKER_WIDTH = 7; // px py pz qx qy qz qw
const ABSENT_ROW: Tracker = [0, 0, 0, 0, 0, 0, 1]; // origin, identity rotation
const NORM2_LO = (1 - QUAT_TOLERANCE) ** 2;
const NORM2_HI = (1 + QUAT_TOLERANCE) ** 2;

/** Whether `key` is present (nil counts as absent). */
export function has(m: WireMap, key: string): boolean {
  const v = m.get(key);
  return v !== undefined && v !== null;
}

function get(m: WireMap, key: string, at: string): Wire {
  const v = m.get(key);
  if (v === undefined || v === null) {
    throw new BadFieldError(`missing field ${at}${key}`, { field: at + key });
  }
  return v;
}

function bad(path: string, expected: string): BadFieldError {
  return new BadFieldError(`${path}: expected ${expected}`, { field: path });
}

/** A msgpack number (int or float) as a JS number, or undefined for anything else. */
function num(v: Wire | undefined): number | undefined {
  if (typeof v === "number") return v;
  if (v instanceof Float64) return v.value;
  return undefined;
}

export function asInt(m: WireMap, key: string, lo: number, hi: number, at = ""): number {
  const v = get(m, key, at);
  if (typeof v !== "number") throw bad(at + key, "an integer");
  if (!(lo <= v && v <= hi)) {
    throw new OutOfRangeError(`${at}${key}=${v} outside [${lo}, ${hi}]`, { field: at + key });
  }
  return v;
}

/** A number (float64, float32 or int on the wire) in `[lo, hi]`, finite. */
export function asFloat(m: WireMap, key: string, lo: number, hi: number, at = ""): number {
  const v = num(get(m, key, at));
  if (v === undefined) throw bad(at + key, "a number");
  if (!(lo <= v && v <= hi)) {
    throw new OutOfRangeError(`${at}${key}=${v} outside [${lo}, ${hi}]`, { field: at + key });
  }
  return v;
}

export function asBool(m: WireMap, key: string, at = ""): boolean {
  const v = get(m, key, at);
  if (typeof v !== "boolean") throw bad(at + key, "a boolean");
  return v;
}

/** A string of `minBytes`..`maxBytes` UTF-8 bytes. */
export function asStr(m: WireMap, key: string, maxBytes: number, minBytes = 1, at = ""): string {
  const v = get(m, key, at);
  if (typeof v !== "string") throw bad(at + key, "a string");
  const n = utf8Length(v);
  if (!(minBytes <= n && n <= maxBytes)) {
    throw new OutOfRangeError(`${at}${key} is ${n} bytes, not ${minBytes}..${maxBytes}`, {
      field: at + key,
    });
  }
  return v;
}

/** A room name or id: 1..maxBytes of `[A-Za-z0-9_.:-]`. */
export function asId(m: WireMap, key: string, maxBytes: number, at = ""): string {
  const v = asStr(m, key, maxBytes, 1, at);
  if (!ID_PATTERN.test(v)) throw bad(at + key, "only A-Z a-z 0-9 _ . : -");
  return v;
}

/** A display name: 1..maxBytes, no control characters. */
export function asName(m: WireMap, key: string, maxBytes: number, at = ""): string {
  const v = asStr(m, key, maxBytes, 1, at);
  if (CONTROL.test(v)) throw bad(at + key, "no control characters");
  return v;
}

export function asEnum<T extends string>(
  m: WireMap,
  key: string,
  options: readonly T[],
  at = "",
): T {
  const v = get(m, key, at);
  if (typeof v !== "string" || !(options as readonly string[]).includes(v)) {
    throw bad(at + key, "one of " + options.join(", "));
  }
  return v as T;
}

export function asList(m: WireMap, key: string, maxLen: number, at = ""): readonly Wire[] {
  const v = get(m, key, at);
  if (!Array.isArray(v)) throw bad(at + key, "an array");
  if (v.length > maxLen) {
    throw new OutOfRangeError(`${at}${key} has ${v.length} items, max ${maxLen}`, {
      field: at + key,
    });
  }
  return v as readonly Wire[];
}

export function asMap(m: WireMap, key: string, at = ""): WireMap {
  const v = get(m, key, at);
  if (!(v instanceof Map)) throw bad(at + key, "a map");
  return v;
}

export function asBin(m: WireMap, key: string, size: number, at = ""): Uint8Array {
  const v = get(m, key, at);
  if (!(v instanceof Uint8Array) || v.length !== size) throw bad(at + key, `bin of ${size} bytes`);
  return v;
}

/** A world position `[x, y, z]` in metres, each within +-MAX_COORD_M. */
export function asPoint(m: WireMap, key: string, at = ""): [number, number, number] {
  const v = get(m, key, at);
  const path = at + key;
  if (!Array.isArray(v) || v.length !== 3) throw bad(path, "an array of 3 numbers");
  const xyz = (v as readonly Wire[]).map(num);
  const [x, y, z] = xyz;
  if (x === undefined || y === undefined || z === undefined) {
    throw bad(path, "an array of 3 numbers");
  }
  if (!(Math.abs(x) <= MAX_COORD_M && Math.abs(y) <= MAX_COORD_M && Math.abs(z) <= MAX_COORD_M)) {
    throw new OutOfRangeError(`${path} outside +-${MAX_COORD_M} m or not finite`, { field: path });
  }
  return [x, y, z];
}

/**
 * 4 trackers `[px, py, pz, qx, qy, qz, qw]`. Slots whose `valid` bit is clear are
 * only type-checked and come back as the origin with the identity rotation.
 * Quaternions within the tolerance are renormalised with the spec's arithmetic:
 * `n = sqrt(((qx*qx + qy*qy) + qz*qz) + qw*qw)`, then each component `/ n`.
 */
export function asTrackers(m: WireMap, key: string, valid = ALL_TRACKERS_VALID): Trackers {
  const rows = get(m, key, "");
  if (!Array.isArray(rows) || rows.length !== NUM_TRACKERS) {
    throw bad(key, `an array of ${NUM_TRACKERS} trackers`);
  }
  return asRows(rows as readonly Wire[], key, valid) as unknown as Trackers;
}

/**
 * A tracker set's 1 to `maxSites` rows, checked as {@link asTrackers} checks trackers,
 * with `valid` (absent: all) a bit mask over them (bits beyond the rows: OUT_OF_RANGE).
 */
export function asSites(
  m: WireMap,
  key: string,
  maxSites: number,
  valid?: number,
): { rows: Tracker[]; valid: number } {
  const rows = get(m, key, "");
  if (!Array.isArray(rows) || rows.length < 1 || rows.length > maxSites) {
    throw bad(key, `an array of 1 to ${maxSites} sites`);
  }
  const full = 2 ** rows.length - 1;
  if (valid !== undefined && valid > full) {
    throw new OutOfRangeError(`valid ${valid} has bits beyond the ${rows.length} sites`, {
      field: "valid",
    });
  }
  const mask = valid ?? full;
  return { rows: asRows(rows as readonly Wire[], key, mask), valid: mask };
}

function asRows(rows: readonly Wire[], key: string, valid: number): Tracker[] {
  const out: Tracker[] = [];
  (rows as readonly Wire[]).forEach((row, i) => {
    const path = `${key}[${i}]`;
    if (!Array.isArray(row) || row.length !== TRACKER_WIDTH) {
      throw bad(path, `an array of ${TRACKER_WIDTH} numbers`);
    }
    const v = (row as readonly Wire[]).map(num);
    if (v.some((x) => x === undefined)) throw bad(path, `an array of ${TRACKER_WIDTH} numbers`);
    if (!((valid >> i) & 1)) {
      out.push(ABSENT_ROW);
      return;
    }
    const [px, py, pz, qx, qy, qz, qw] = v as [number, number, number, number, number, number, number];
    if (!(Math.abs(px) <= MAX_COORD_M && Math.abs(py) <= MAX_COORD_M && Math.abs(pz) <= MAX_COORD_M)) {
      throw new OutOfRangeError(`${path} position outside +-${MAX_COORD_M} m or not finite`, {
        field: path,
      });
    }
    const n2 = qx * qx + qy * qy + qz * qz + qw * qw;
    if (!(NORM2_LO <= n2 && n2 <= NORM2_HI)) {
      if (![qx, qy, qz, qw].every(Number.isFinite)) {
        throw new OutOfRangeError(`${path} orientation not finite`, { field: path });
      }
      throw new NotNormalisedError(`${path} orientation has norm ${Math.sqrt(n2).toFixed(6)}`, {
        field: path,
      });
    }
    const n = Math.sqrt(n2);
    out.push([px, py, pz, qx / n, qy / n, qz / n, qw / n]);
  });
  return out;
}
