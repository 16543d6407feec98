/**
 * A small, strict msgpack reader and writer for protocols v1 and v2 (pure: bytes in, values out).
 *
 * Why not a general msgpack library: the spec needs three things they do not give.
 *
 * 1. **Int and float stay apart.** An int field refuses `7.0` (`BAD_FIELD`), so the
 *    reader must report whether a number was a msgpack int or float. Readers that
 *    return plain JS numbers (`@msgpack/msgpack` decodes float64 `7.0` as `7`) lose it.
 * 2. **Per-field float64.** Canonical bytes write every float field as float64, even
 *    `1.0`, and every int field in its smallest int form. A writer-wide switch
 *    (`forceIntegerToFloat`) cannot do both in one message, so float fields are
 *    wrapped in {@link Float64} here and the writer follows the wrapper.
 * 3. **Bounds at the header.** A str, bin, array or map over its structural bound is
 *    `TOO_LARGE` before anything is allocated; string map keys only; no ext types;
 *    invalid UTF-8 is `MALFORMED`.
 *
 * Values: `null`, `boolean`, `number` (a msgpack int), {@link Float64} (a msgpack
 * float), `string`, `Uint8Array` (bin), arrays and `Map<string, Wire>` (maps keep
 * their key order; a `Map` also keeps `__proto__` an ordinary key).
 */

import { MalformedError, TooLargeError } from "./errors.js";

/** A msgpack float: written as float64 (`0xcb`), whatever its value. */
export class Float64 {
  constructor(readonly value: number) {}
}

/** One msgpack value as this codec reads and writes it. */
export type Wire = null | boolean | number | Float64 | string | Uint8Array | WireArray | WireMap;
export type WireArray = readonly Wire[];
export type WireMap = ReadonlyMap<string, Wire>;

/** Structural bounds of every message (v2 raises the bin bound for server messages; see `unpack`) (`proto/README.md`, "Structural bounds"). */
export const MAX_STR_BYTES = 4096;
export const MAX_BIN_BYTES = 256;
export const MAX_ARRAY_LEN = 64;
export const MAX_MAP_LEN = 32;
/** Maps and arrays nested deeper than this (the root map is 1) are MALFORMED. */
export const MAX_DEPTH = 8;
/** The reader gives up at once past this depth (as msgpack-python's stack limit does). */
const HARD_DEPTH = 1024;

interface TextCodecs {
  TextEncoder: new () => { encode(s: string): Uint8Array };
  TextDecoder: new (
    label: string,
    options: { fatal: boolean },
  ) => { decode(b: Uint8Array): string };
}
// Both exist in every browser and in Node >= 11; looked up untyped so that the SDK
// compiles without the DOM or Node type libraries.
const codecs = globalThis as unknown as TextCodecs;
const utf8Encoder = new codecs.TextEncoder();
const utf8Decoder = new codecs.TextDecoder("utf-8", { fatal: true });

/** UTF-8 bytes of `s`. */
export function utf8(s: string): Uint8Array {
  return utf8Encoder.encode(s);
}

/** UTF-8 byte length of `s`, without allocating. Lone surrogates count 3 (as U+FFFD). */
export function utf8Length(s: string): number {
  let n = 0;
  for (let i = 0; i < s.length; i++) {
    const c = s.charCodeAt(i);
    if (c < 0x80) n += 1;
    else if (c < 0x800) n += 2;
    else if (c >= 0xd800 && c <= 0xdbff && i + 1 < s.length) {
      const d = s.charCodeAt(i + 1);
      if (d >= 0xdc00 && d <= 0xdfff) {
        n += 4;
        i++;
      } else n += 3;
    } else n += 3;
  }
  return n;
}

// --- reader -------------------------------------------------------------------------------

/** Result of {@link unpack}: the value, and whether any map/array sat deeper than 8. */
export interface Unpacked {
  value: Wire;
  tooDeep: boolean;
}

/**
 * Read exactly one msgpack value from `bytes`.
 *
 * Throws MALFORMED for invalid or truncated bytes, trailing data, ext types, a
 * non-string map key or invalid UTF-8, and TOO_LARGE for a str, bin, array or map
 * over its structural bound (at its header), whichever comes first in the bytes.
 * Nesting deeper than {@link MAX_DEPTH} is reported in `tooDeep`, not thrown, so the
 * caller can apply the spec's order of checks. `maxBinBytes` is the bin bound: 256 in
 * v1, the message cap (16384) for a v2 server message (`poses.data`).
 */
export function unpack(bytes: Uint8Array, maxBinBytes = MAX_BIN_BYTES): Unpacked {
  const r = new Reader(bytes, maxBinBytes);
  const value = r.value(1);
  if (r.pos !== bytes.length) {
    throw new MalformedError(`trailing bytes after the msgpack value (${bytes.length - r.pos})`);
  }
  return { value, tooDeep: r.tooDeep };
}

class Reader {
  pos = 0;
  tooDeep = false;
  private readonly view: DataView;

  constructor(
    private readonly bytes: Uint8Array,
    private readonly maxBin: number,
  ) {
    this.view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  }

  private need(n: number): void {
    if (this.pos + n > this.bytes.length) throw new MalformedError("truncated msgpack");
  }

  private u8(): number {
    this.need(1);
    return this.view.getUint8(this.pos++);
  }

  private u16(): number {
    this.need(2);
    const v = this.view.getUint16(this.pos);
    this.pos += 2;
    return v;
  }

  private u32(): number {
    this.need(4);
    const v = this.view.getUint32(this.pos);
    this.pos += 4;
    return v;
  }

  value(depth: number): Wire {
    const b = this.u8();
    if (b <= 0x7f) return b;
    if (b >= 0xe0) return b - 0x100;
    if (b >= 0x80 && b <= 0x8f) return this.map(b & 0x0f, depth);
    if (b >= 0x90 && b <= 0x9f) return this.array(b & 0x0f, depth);
    if (b >= 0xa0 && b <= 0xbf) return this.str(b & 0x1f);
    const v = this.view;
    switch (b) {
      case 0xc0:
        return null;
      case 0xc2:
        return false;
      case 0xc3:
        return true;
      case 0xc4:
        return this.bin(this.u8());
      case 0xc5:
        return this.bin(this.u16());
      case 0xc6:
        return this.bin(this.u32());
      case 0xca: {
        this.need(4);
        const f = v.getFloat32(this.pos);
        this.pos += 4;
        return new Float64(f);
      }
      case 0xcb: {
        this.need(8);
        const f = v.getFloat64(this.pos);
        this.pos += 8;
        return new Float64(f);
      }
      case 0xcc:
        return this.u8();
      case 0xcd:
        return this.u16();
      case 0xce:
        return this.u32();
      case 0xcf: {
        // Above 2**53 the JS number is inexact; every v1 int range ends at 2**32 - 1,
        // so an inexact value is refused all the same.
        this.need(8);
        const n = Number(v.getBigUint64(this.pos));
        this.pos += 8;
        return n;
      }
      case 0xd0: {
        this.need(1);
        return v.getInt8(this.pos++);
      }
      case 0xd1: {
        this.need(2);
        const n = v.getInt16(this.pos);
        this.pos += 2;
        return n;
      }
      case 0xd2: {
        this.need(4);
        const n = v.getInt32(this.pos);
        this.pos += 4;
        return n;
      }
      case 0xd3: {
        this.need(8);
        const n = Number(v.getBigInt64(this.pos));
        this.pos += 8;
        return n;
      }
      case 0xd9:
        return this.str(this.u8());
      case 0xda:
        return this.str(this.u16());
      case 0xdb:
        return this.str(this.u32());
      case 0xdc:
        return this.array(this.u16(), depth);
      case 0xdd:
        return this.array(this.u32(), depth);
      case 0xde:
        return this.map(this.u16(), depth);
      case 0xdf:
        return this.map(this.u32(), depth);
      case 0xc7:
      case 0xc8:
      case 0xc9:
      case 0xd4:
      case 0xd5:
      case 0xd6:
      case 0xd7:
      case 0xd8:
        throw new MalformedError("msgpack ext types are not used by posecast");
      default: // 0xc1: never used
        throw new MalformedError(`invalid msgpack byte 0x${b.toString(16)}`);
    }
  }

  private str(n: number): string {
    if (n > MAX_STR_BYTES) throw new TooLargeError(`str of ${n} bytes, limit ${MAX_STR_BYTES}`);
    this.need(n);
    const raw = this.bytes.subarray(this.pos, this.pos + n);
    this.pos += n;
    try {
      return utf8Decoder.decode(raw);
    } catch {
      throw new MalformedError("a str is not valid UTF-8");
    }
  }

  private bin(n: number): Uint8Array {
    if (n > this.maxBin) throw new TooLargeError(`bin of ${n} bytes, limit ${this.maxBin}`);
    this.need(n);
    const out = this.bytes.slice(this.pos, this.pos + n);
    this.pos += n;
    return out;
  }

  private enter(depth: number): void {
    if (depth > MAX_DEPTH) this.tooDeep = true;
    if (depth > HARD_DEPTH) throw new MalformedError(`nested deeper than ${HARD_DEPTH}`);
  }

  private array(n: number, depth: number): Wire[] {
    if (n > MAX_ARRAY_LEN) throw new TooLargeError(`array of ${n} items, limit ${MAX_ARRAY_LEN}`);
    this.enter(depth);
    const out: Wire[] = [];
    for (let i = 0; i < n; i++) out.push(this.value(depth + 1));
    return out;
  }

  private map(n: number, depth: number): Map<string, Wire> {
    if (n > MAX_MAP_LEN) throw new TooLargeError(`map of ${n} entries, limit ${MAX_MAP_LEN}`);
    this.enter(depth);
    const out = new Map<string, Wire>();
    for (let i = 0; i < n; i++) {
      const key = this.value(depth + 1);
      if (typeof key !== "string") throw new MalformedError("map keys must be strings");
      out.set(key, this.value(depth + 1));
    }
    return out;
  }
}

// --- writer -------------------------------------------------------------------------------

/**
 * The msgpack bytes of `value`, each item in its smallest form; {@link Float64} as
 * float64. A plain JS number must be a safe integer (a float field that forgot its
 * wrapper is a programming error, not something to guess about).
 */
export function pack(value: Wire): Uint8Array {
  const w = new Writer();
  w.value(value);
  return w.bytes();
}

class Writer {
  private buf = new Uint8Array(512);
  private view = new DataView(this.buf.buffer);
  private pos = 0;

  bytes(): Uint8Array {
    return this.buf.slice(0, this.pos);
  }

  private room(n: number): void {
    if (this.pos + n <= this.buf.length) return;
    let size = this.buf.length * 2;
    while (size < this.pos + n) size *= 2;
    const next = new Uint8Array(size);
    next.set(this.buf.subarray(0, this.pos));
    this.buf = next;
    this.view = new DataView(next.buffer);
  }

  private u8(b: number): void {
    this.room(1);
    this.view.setUint8(this.pos++, b);
  }

  private head(b: number, n: number, size: 1 | 2 | 4): void {
    this.room(1 + size);
    this.view.setUint8(this.pos++, b);
    if (size === 1) this.view.setUint8(this.pos, n);
    else if (size === 2) this.view.setUint16(this.pos, n);
    else this.view.setUint32(this.pos, n);
    this.pos += size;
  }

  value(v: Wire): void {
    if (v === null) this.u8(0xc0);
    else if (v === true) this.u8(0xc3);
    else if (v === false) this.u8(0xc2);
    else if (typeof v === "number") this.int(v);
    else if (v instanceof Float64) {
      this.room(9);
      this.view.setUint8(this.pos, 0xcb);
      this.view.setFloat64(this.pos + 1, v.value);
      this.pos += 9;
    } else if (typeof v === "string") this.str(v);
    else if (v instanceof Uint8Array) {
      const n = v.length;
      if (n <= 0xff) this.head(0xc4, n, 1);
      else if (n <= 0xffff) this.head(0xc5, n, 2);
      else this.head(0xc6, n, 4);
      this.raw(v);
    } else if (v instanceof Map) {
      const n = v.size;
      if (n <= 15) this.u8(0x80 | n);
      else if (n <= 0xffff) this.head(0xde, n, 2);
      else this.head(0xdf, n, 4);
      for (const [k, item] of v) {
        this.str(k);
        this.value(item);
      }
    } else {
      const items = v as WireArray;
      const n = items.length;
      if (n <= 15) this.u8(0x90 | n);
      else if (n <= 0xffff) this.head(0xdc, n, 2);
      else this.head(0xdd, n, 4);
      for (const item of items) this.value(item);
    }
  }

  private raw(b: Uint8Array): void {
    this.room(b.length);
    this.buf.set(b, this.pos);
    this.pos += b.length;
  }

  private str(s: string): void {
    const b = utf8(s);
    const n = b.length;
    if (n <= 31) this.u8(0xa0 | n);
    else if (n <= 0xff) this.head(0xd9, n, 1);
    else if (n <= 0xffff) this.head(0xda, n, 2);
    else this.head(0xdb, n, 4);
    this.raw(b);
  }

  private int(n: number): void {
    if (!Number.isSafeInteger(n)) {
      throw new TypeError(`msgpack int expected, got ${n} (wrap float fields in Float64)`);
    }
    const v = this.view;
    if (n >= 0) {
      if (n <= 0x7f) this.u8(n);
      else if (n <= 0xff) this.head(0xcc, n, 1);
      else if (n <= 0xffff) this.head(0xcd, n, 2);
      else if (n <= 0xffffffff) this.head(0xce, n, 4);
      else {
        this.room(9);
        v.setUint8(this.pos, 0xcf);
        v.setBigUint64(this.pos + 1, BigInt(n));
        this.pos += 9;
      }
    } else if (n >= -32) this.u8(n + 0x100);
    else if (n >= -0x80) {
      this.room(2);
      v.setUint8(this.pos, 0xd0);
      v.setInt8(this.pos + 1, n);
      this.pos += 2;
    } else if (n >= -0x8000) {
      this.room(3);
      v.setUint8(this.pos, 0xd1);
      v.setInt16(this.pos + 1, n);
      this.pos += 3;
    } else if (n >= -0x80000000) {
      this.room(5);
      v.setUint8(this.pos, 0xd2);
      v.setInt32(this.pos + 1, n);
      this.pos += 5;
    } else {
      this.room(9);
      v.setUint8(this.pos, 0xd3);
      v.setBigInt64(this.pos + 1, BigInt(n));
      this.pos += 9;
    }
  }
}
