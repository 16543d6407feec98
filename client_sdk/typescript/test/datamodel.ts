/**
 * The JSON data model of posecast messages (proto/README.md, "The JSON data model";
 * proto/datamodel.py is the Python twin): one msgpack message as the JSON value that
 * proto/schema.json validates. Written apart from the SDK's reader on purpose: that one
 * refuses what breaks a structural bound at its header (TOO_LARGE), and the schema is
 * to see such values and refuse them itself.
 *
 * nil, bool, str, array as themselves; an int or a finite float as a number; a
 * non-finite float as `{"$float": "NaN" | "Infinity" | "-Infinity"}`; a bin as
 * `{"$bin": hex}`; a map as an object in key order. {@link NotRepresentableError} for bytes
 * with no rendering: not exactly one msgpack value, an ext type, invalid UTF-8, a
 * non-str map key, a key twice, a map whose one key is `$bin` or `$float`, more than
 * 64 nested arrays and maps.
 */

export class NotRepresentableError extends Error {}

const MAX_NESTING = 64;
const RESERVED = new Set(["$bin", "$float"]);
const utf8 = new TextDecoder("utf-8", { fatal: true });

export function render(bytes: Uint8Array): unknown {
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  let pos = 0;

  const need = (n: number): void => {
    if (pos + n > bytes.length) throw new NotRepresentableError("truncated");
  };
  const take = (n: number): Uint8Array => {
    need(n);
    const out = bytes.subarray(pos, pos + n);
    pos += n;
    return out;
  };
  const u8 = (): number => take(1)[0]!;
  const u16 = (): number => (need(2), (pos += 2), view.getUint16(pos - 2));
  const u32 = (): number => (need(4), (pos += 4), view.getUint32(pos - 4));
  const float = (x: number): unknown =>
    Number.isNaN(x) ? { $float: "NaN" } : Number.isFinite(x) ? x : { $float: x > 0 ? "Infinity" : "-Infinity" };
  const str = (n: number): string => {
    try {
      return utf8.decode(take(n));
    } catch {
      throw new NotRepresentableError("a str that is not UTF-8");
    }
  };
  const bin = (n: number): unknown => ({ $bin: Buffer.from(take(n)).toString("hex") });

  const array = (n: number, depth: number): unknown[] => {
    if (depth >= MAX_NESTING) throw new NotRepresentableError("nested too deep");
    need(n); // every item is at least one byte: refuse a lying header before allocating
    const out: unknown[] = [];
    for (let i = 0; i < n; i++) out.push(value(depth + 1));
    return out;
  };
  const map = (n: number, depth: number): Record<string, unknown> => {
    if (depth >= MAX_NESTING) throw new NotRepresentableError("nested too deep");
    need(2 * n);
    const out: Record<string, unknown> = {};
    for (let i = 0; i < n; i++) {
      const key = value(depth + 1);
      if (typeof key !== "string") throw new NotRepresentableError("a map key that is not a str");
      if (Object.prototype.hasOwnProperty.call(out, key)) throw new NotRepresentableError("a key twice");
      // defineProperty: "__proto__" is an ordinary key here.
      Object.defineProperty(out, key, { value: value(depth + 1), enumerable: true, writable: true, configurable: true });
    }
    const keys = Object.keys(out);
    if (keys.length === 1 && RESERVED.has(keys[0]!)) throw new NotRepresentableError("a map shaped like a bin or a float");
    return out;
  };

  function value(depth: number): unknown {
    const b = u8();
    if (b <= 0x7f) return b;
    if (b >= 0xe0) return b - 0x100;
    if (b >= 0x80 && b <= 0x8f) return map(b & 0x0f, depth);
    if (b >= 0x90 && b <= 0x9f) return array(b & 0x0f, depth);
    if (b >= 0xa0 && b <= 0xbf) return str(b & 0x1f);
    switch (b) {
      case 0xc0:
        return null;
      case 0xc2:
        return false;
      case 0xc3:
        return true;
      case 0xc4:
        return bin(u8());
      case 0xc5:
        return bin(u16());
      case 0xc6:
        return bin(u32());
      case 0xca:
        need(4);
        pos += 4;
        return float(view.getFloat32(pos - 4));
      case 0xcb:
        need(8);
        pos += 8;
        return float(view.getFloat64(pos - 8));
      case 0xcc:
        return u8();
      case 0xcd:
        return u16();
      case 0xce:
        return u32();
      case 0xcf:
        need(8);
        pos += 8;
        return Number(view.getBigUint64(pos - 8));
      case 0xd0:
        need(1);
        pos += 1;
        return view.getInt8(pos - 1);
      case 0xd1:
        need(2);
        pos += 2;
        return view.getInt16(pos - 2);
      case 0xd2:
        need(4);
        pos += 4;
        return view.getInt32(pos - 4);
      case 0xd3:
        need(8);
        pos += 8;
        return Number(view.getBigInt64(pos - 8));
      case 0xd9:
        return str(u8());
      case 0xda:
        return str(u16());
      case 0xdb:
        return str(u32());
      case 0xdc:
        return array(u16(), depth);
      case 0xdd:
        return array(u32(), depth);
      case 0xde:
        return map(u16(), depth);
      case 0xdf:
        return map(u32(), depth);
      default: // 0xc1 (never used), 0xc7-0xc9 and 0xd4-0xd8 (ext types)
        throw new NotRepresentableError(`the byte 0x${b.toString(16)}`);
    }
  }

  const out = value(0);
  if (pos !== bytes.length) throw new NotRepresentableError("trailing bytes");
  return out;
}
