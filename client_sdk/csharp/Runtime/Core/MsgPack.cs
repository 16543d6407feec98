// A msgpack subset: a bounded reader and the canonical writer (proto/README.md,
// "Encoding"). Pure: bytes in, values out.
//
// The reader refuses, in stream order, what the spec's step 2 refuses: invalid bytes
// (0xc1), truncation, trailing bytes, invalid UTF-8, a map key that is not a str or
// bin, any ext type (MALFORMED), and a str, bin, array or map over its structural
// bound, at its header before anything is allocated (TOO_LARGE). What the spec
// checks after the root's kind (nesting deeper than 8, a bin map key) is recorded
// while reading and reported by the codec in the spec's order.
//
// The writer writes the canonical form: ints, strs, bins, arrays and maps in their
// smallest msgpack form, every float as float64, map entries in the order given.

using System;
using System.Collections.Generic;
using System.Text;

namespace Posecast.Client
{
    public enum MsgKind { Nil, Bool, Int, Float, Str, Bin, Array, Map }

    /// <summary>One msgpack value. Maps keep their entries in wire order.</summary>
    public sealed class MsgValue
    {
        public readonly MsgKind Kind;
        public readonly bool Bool;
        /// <summary>An Int's value; for a uint64 above long.MaxValue, see IsHugeUInt.</summary>
        public readonly long Int;
        /// <summary>An Int held as uint64 over long.MaxValue (out of range for every field).</summary>
        public readonly bool IsHugeUInt;
        public readonly double Float;
        public readonly string Str;
        public readonly byte[] Bin;
        public readonly List<MsgValue> Items;
        public readonly List<KeyValuePair<string, MsgValue>> Entries;
        private Dictionary<string, MsgValue> _index;

        private MsgValue(MsgKind kind, bool b = false, long i = 0, bool huge = false, double f = 0,
                         string s = null, byte[] bin = null, List<MsgValue> items = null,
                         List<KeyValuePair<string, MsgValue>> entries = null)
        {
            Kind = kind; Bool = b; Int = i; IsHugeUInt = huge; Float = f; Str = s; Bin = bin;
            Items = items; Entries = entries;
        }

        public static readonly MsgValue Nil = new MsgValue(MsgKind.Nil);
        public static readonly MsgValue True = new MsgValue(MsgKind.Bool, b: true);
        public static readonly MsgValue False = new MsgValue(MsgKind.Bool, b: false);
        public static MsgValue Of(bool v) { return v ? True : False; }
        public static MsgValue Of(long v) { return new MsgValue(MsgKind.Int, i: v); }
        public static MsgValue HugeUInt(ulong v) { return new MsgValue(MsgKind.Int, i: unchecked((long)v), huge: true); }
        public static MsgValue Of(double v) { return new MsgValue(MsgKind.Float, f: v); }
        public static MsgValue Of(string v) { return new MsgValue(MsgKind.Str, s: v); }
        public static MsgValue Of(byte[] v) { return new MsgValue(MsgKind.Bin, bin: v); }
        public static MsgValue Array(List<MsgValue> items) { return new MsgValue(MsgKind.Array, items: items); }
        public static MsgValue Array(params MsgValue[] items) { return Array(new List<MsgValue>(items)); }
        public static MsgValue Map(List<KeyValuePair<string, MsgValue>> entries)
        {
            return new MsgValue(MsgKind.Map, entries: entries);
        }
        public static MsgValue NewMap() { return Map(new List<KeyValuePair<string, MsgValue>>()); }

        /// <summary>Append an entry to a map built by the program (canonical order).</summary>
        public MsgValue Add(string key, MsgValue value)
        {
            Entries.Add(new KeyValuePair<string, MsgValue>(key, value));
            _index = null;
            return this;
        }

        /// <summary>A map's value for key (the last one on duplicates), or null when absent.</summary>
        public MsgValue Get(string key)
        {
            if (_index == null)
            {
                _index = new Dictionary<string, MsgValue>(Entries.Count);
                foreach (var e in Entries) _index[e.Key] = e.Value;
            }
            MsgValue v;
            return _index.TryGetValue(key, out v) ? v : null;
        }

        /// <summary>The distinct keys of a map.</summary>
        public int DistinctKeys { get { Get(""); return _index.Count; } }
        public IEnumerable<string> Keys { get { Get(""); return _index.Keys; } }

        /// <summary>Whether the value is a number (an int or a float; never a bool).</summary>
        public bool IsNumber { get { return Kind == MsgKind.Int || Kind == MsgKind.Float; } }

        /// <summary>A number as a double (ints exactly as Python's float(int) rounds them).</summary>
        public double AsDouble
        {
            get
            {
                if (Kind == MsgKind.Float) return Float;
                return IsHugeUInt ? (double)unchecked((ulong)Int) : (double)Int;
            }
        }

        /// <summary>Structural equality, map order and int/float kinds included.</summary>
        public bool SameAs(MsgValue o)
        {
            if (o == null || Kind != o.Kind) return false;
            switch (Kind)
            {
                case MsgKind.Nil: return true;
                case MsgKind.Bool: return Bool == o.Bool;
                case MsgKind.Int: return Int == o.Int && IsHugeUInt == o.IsHugeUInt;
                case MsgKind.Float: return Float.Equals(o.Float);
                case MsgKind.Str: return Str == o.Str;
                case MsgKind.Bin:
                    if (Bin.Length != o.Bin.Length) return false;
                    for (int i = 0; i < Bin.Length; i++) if (Bin[i] != o.Bin[i]) return false;
                    return true;
                case MsgKind.Array:
                    if (Items.Count != o.Items.Count) return false;
                    for (int i = 0; i < Items.Count; i++) if (!Items[i].SameAs(o.Items[i])) return false;
                    return true;
                default:
                    if (Entries.Count != o.Entries.Count) return false;
                    for (int i = 0; i < Entries.Count; i++)
                        if (Entries[i].Key != o.Entries[i].Key || !Entries[i].Value.SameAs(o.Entries[i].Value)) return false;
                    return true;
            }
        }

        public override string ToString()
        {
            switch (Kind)
            {
                case MsgKind.Nil: return "nil";
                case MsgKind.Bool: return Bool ? "true" : "false";
                case MsgKind.Int: return IsHugeUInt ? unchecked((ulong)Int).ToString() : Int.ToString();
                case MsgKind.Float: return Float.ToString("R", System.Globalization.CultureInfo.InvariantCulture);
                case MsgKind.Str: return "\"" + Str + "\"";
                case MsgKind.Bin: return "bin(" + Bin.Length + ")";
                case MsgKind.Array: return "[" + string.Join(", ", Items) + "]";
                default:
                    var parts = new List<string>();
                    foreach (var e in Entries) parts.Add(e.Key + ": " + e.Value);
                    return "{" + string.Join(", ", parts) + "}";
            }
        }
    }

    /// <summary>The structural bounds one read applies (proto/README.md, "Structural bounds").</summary>
    public struct MsgBounds
    {
        public int MaxStrBytes, MaxBinBytes, MaxArrayLen, MaxMapLen;
    }

    /// <summary>Reads exactly one msgpack value from a whole message.</summary>
    public sealed class MsgPackReader
    {
        // A reader gives up past this depth at once (as msgpack-python's own stack does);
        // deeper than MaxDepth (8) but within it is reported later, in the spec's order.
        private const int HardDepth = 1024;

        private readonly byte[] _buf;
        private readonly int _end;
        private readonly MsgBounds _bounds;
        private int _pos;

        /// <summary>The deepest container nesting seen (the root is 1).</summary>
        public int MaxDepthSeen { get; private set; }
        /// <summary>A map key was a bin: MALFORMED, reported after the root check.</summary>
        public bool BinKeySeen { get; private set; }

        public MsgPackReader(byte[] buf, int offset, int count, MsgBounds bounds)
        {
            _buf = buf; _pos = offset; _end = offset + count; _bounds = bounds;
        }

        /// <summary>The one value of the buffer; MALFORMED for trailing bytes.</summary>
        public MsgValue ReadWhole()
        {
            if (_pos >= _end) throw ErrorCodes.Malformed("msgpack: no data");
            var v = Read(1);
            if (_pos != _end) throw ErrorCodes.Malformed("msgpack: trailing bytes after the value");
            return v;
        }

        private void Need(int n)
        {
            if (_end - _pos < n) throw ErrorCodes.Malformed("msgpack: truncated");
        }

        private byte U8() { Need(1); return _buf[_pos++]; }

        private ulong Be(int n)
        {
            Need(n);
            ulong v = 0;
            for (int i = 0; i < n; i++) v = (v << 8) | _buf[_pos + i];
            _pos += n;
            return v;
        }

        private MsgValue Read(int depth)
        {
            byte b = U8();
            if (b <= 0x7f) return MsgValue.Of((long)b);
            if (b >= 0xe0) return MsgValue.Of((long)(sbyte)b);
            if (b <= 0x8f) return ReadMap((ulong)(b & 0x0f), depth);
            if (b <= 0x9f) return ReadArray((ulong)(b & 0x0f), depth);
            if (b <= 0xbf) return ReadStr((ulong)(b & 0x1f));
            switch (b)
            {
                case 0xc0: return MsgValue.Nil;
                case 0xc2: return MsgValue.False;
                case 0xc3: return MsgValue.True;
                case 0xc4: return ReadBin(Be(1));
                case 0xc5: return ReadBin(Be(2));
                case 0xc6: return ReadBin(Be(4));
                case 0xca:
                {
                    int bits = unchecked((int)(uint)Be(4));
                    return MsgValue.Of((double)BitConverter.ToSingle(BitConverter.GetBytes(bits), 0));
                }
                case 0xcb: return MsgValue.Of(BitConverter.Int64BitsToDouble(unchecked((long)Be(8))));
                case 0xcc: return MsgValue.Of((long)Be(1));
                case 0xcd: return MsgValue.Of((long)Be(2));
                case 0xce: return MsgValue.Of((long)Be(4));
                case 0xcf:
                {
                    ulong v = Be(8);
                    return v > long.MaxValue ? MsgValue.HugeUInt(v) : MsgValue.Of((long)v);
                }
                case 0xd0: return MsgValue.Of((long)(sbyte)Be(1));
                case 0xd1: return MsgValue.Of((long)(short)Be(2));
                case 0xd2: return MsgValue.Of((long)(int)Be(4));
                case 0xd3: return MsgValue.Of(unchecked((long)Be(8)));
                case 0xd9: return ReadStr(Be(1));
                case 0xda: return ReadStr(Be(2));
                case 0xdb: return ReadStr(Be(4));
                case 0xdc: return ReadArray(Be(2), depth);
                case 0xdd: return ReadArray(Be(4), depth);
                case 0xde: return ReadMap(Be(2), depth);
                case 0xdf: return ReadMap(Be(4), depth);
                case 0xc1: throw ErrorCodes.Malformed("msgpack: 0xc1 is never used");
                default: // c7 c8 c9 d4..d8: ext types are not used by posecast
                    throw ErrorCodes.Malformed("msgpack ext types are not used by posecast");
            }
        }

        private MsgValue ReadStr(ulong n)
        {
            if (n > (ulong)_bounds.MaxStrBytes)
                throw ErrorCodes.TooLarge("msgpack: a str of " + n + " bytes exceeds " + _bounds.MaxStrBytes);
            int len = (int)n;
            Need(len);
            if (!Utf8.IsStrict(_buf, _pos, len)) throw ErrorCodes.Malformed("msgpack: a str that is not UTF-8");
            string s = Encoding.UTF8.GetString(_buf, _pos, len);
            _pos += len;
            return MsgValue.Of(s);
        }

        private MsgValue ReadBin(ulong n)
        {
            if (n > (ulong)_bounds.MaxBinBytes)
                throw ErrorCodes.TooLarge("msgpack: a bin of " + n + " bytes exceeds " + _bounds.MaxBinBytes);
            int len = (int)n;
            Need(len);
            var bin = new byte[len];
            Buffer.BlockCopy(_buf, _pos, bin, 0, len);
            _pos += len;
            return MsgValue.Of(bin);
        }

        private void Enter(int depth)
        {
            if (depth > MaxDepthSeen) MaxDepthSeen = depth;
            if (depth > HardDepth) throw ErrorCodes.Malformed("msgpack: nested too deep");
        }

        private MsgValue ReadArray(ulong n, int depth)
        {
            if (n > (ulong)_bounds.MaxArrayLen)
                throw ErrorCodes.TooLarge("msgpack: an array of " + n + " items exceeds " + _bounds.MaxArrayLen);
            Enter(depth);
            var items = new List<MsgValue>((int)n);
            for (ulong i = 0; i < n; i++) items.Add(Read(depth + 1));
            return MsgValue.Array(items);
        }

        private MsgValue ReadMap(ulong n, int depth)
        {
            if (n > (ulong)_bounds.MaxMapLen)
                throw ErrorCodes.TooLarge("msgpack: a map of " + n + " entries exceeds " + _bounds.MaxMapLen);
            Enter(depth);
            var entries = new List<KeyValuePair<string, MsgValue>>((int)n);
            for (ulong i = 0; i < n; i++)
            {
                var key = Read(depth + 1);
                if (key.Kind == MsgKind.Bin) BinKeySeen = true; // msgpack-python's strict_map_key lets bins by
                else if (key.Kind != MsgKind.Str) throw ErrorCodes.Malformed("msgpack: map keys must be strings");
                var value = Read(depth + 1);
                if (key.Kind == MsgKind.Str) entries.Add(new KeyValuePair<string, MsgValue>(key.Str, value));
            }
            return MsgValue.Map(entries);
        }
    }

    /// <summary>UTF-8 checks: strict validity (no overlongs, surrogates or > U+10FFFF).</summary>
    public static class Utf8
    {
        public static bool IsStrict(byte[] b, int off, int len)
        {
            int i = off, end = off + len;
            while (i < end)
            {
                int c = b[i];
                if (c < 0x80) { i++; continue; }
                int n; int min;
                if ((c & 0xe0) == 0xc0) { n = 1; min = 0x80; c &= 0x1f; }
                else if ((c & 0xf0) == 0xe0) { n = 2; min = 0x800; c &= 0x0f; }
                else if ((c & 0xf8) == 0xf0) { n = 3; min = 0x10000; c &= 0x07; }
                else return false;
                for (int k = 1; k <= n; k++)
                {
                    if (i + k >= end) return false;
                    int cc = b[i + k];
                    if ((cc & 0xc0) != 0x80) return false;
                    c = (c << 6) | (cc & 0x3f);
                }
                if (c < min || c > 0x10ffff || (c >= 0xd800 && c <= 0xdfff)) return false;
                i += n + 1;
            }
            return true;
        }

        public static int ByteCount(string s) { return Encoding.UTF8.GetByteCount(s); }
    }

    /// <summary>The canonical msgpack writer.</summary>
    public sealed class MsgPackWriter
    {
        private byte[] _buf = new byte[256];
        private int _len;

        public byte[] ToArray()
        {
            var out_ = new byte[_len];
            Buffer.BlockCopy(_buf, 0, out_, 0, _len);
            return out_;
        }

        private void Room(int n)
        {
            if (_len + n <= _buf.Length) return;
            var bigger = new byte[Math.Max(_buf.Length * 2, _len + n)];
            Buffer.BlockCopy(_buf, 0, bigger, 0, _len);
            _buf = bigger;
        }

        private void Byte(int b) { Room(1); _buf[_len++] = (byte)b; }

        private void Be(ulong v, int n)
        {
            Room(n);
            for (int i = n - 1; i >= 0; i--) { _buf[_len + i] = (byte)v; v >>= 8; }
            _len += n;
        }

        public void Write(MsgValue v)
        {
            switch (v.Kind)
            {
                case MsgKind.Nil: Byte(0xc0); break;
                case MsgKind.Bool: Byte(v.Bool ? 0xc3 : 0xc2); break;
                case MsgKind.Int:
                    if (v.IsHugeUInt) { Byte(0xcf); Be(unchecked((ulong)v.Int), 8); }
                    else WriteInt(v.Int);
                    break;
                case MsgKind.Float: WriteFloat(v.Float); break;
                case MsgKind.Str: WriteStr(v.Str); break;
                case MsgKind.Bin: WriteBin(v.Bin); break;
                case MsgKind.Array:
                    Header(v.Items.Count, 0x90, 16, 0xdc);
                    foreach (var x in v.Items) Write(x);
                    break;
                default:
                    Header(v.Entries.Count, 0x80, 16, 0xde);
                    foreach (var e in v.Entries) { WriteStr(e.Key); Write(e.Value); }
                    break;
            }
        }

        private void Header(int n, int fix, int fixMax, int b16)
        {
            if (n < fixMax) Byte(fix + n);
            else if (n <= 0xffff) { Byte(b16); Be((ulong)n, 2); }
            else { Byte(b16 + 1); Be((ulong)n, 4); }
        }

        public void WriteInt(long v)
        {
            if (v >= 0)
            {
                if (v < 0x80) Byte((int)v);
                else if (v <= 0xff) { Byte(0xcc); Be((ulong)v, 1); }
                else if (v <= 0xffff) { Byte(0xcd); Be((ulong)v, 2); }
                else if (v <= 0xffffffffL) { Byte(0xce); Be((ulong)v, 4); }
                else { Byte(0xcf); Be((ulong)v, 8); }
            }
            else
            {
                if (v >= -32) Byte((int)(v & 0xff));
                else if (v >= sbyte.MinValue) { Byte(0xd0); Be(unchecked((ulong)v), 1); }
                else if (v >= short.MinValue) { Byte(0xd1); Be(unchecked((ulong)v), 2); }
                else if (v >= int.MinValue) { Byte(0xd2); Be(unchecked((ulong)v), 4); }
                else { Byte(0xd3); Be(unchecked((ulong)v), 8); }
            }
        }

        public void WriteFloat(double v)
        {
            Byte(0xcb);
            Be(unchecked((ulong)BitConverter.DoubleToInt64Bits(v)), 8);
        }

        public void WriteStr(string s)
        {
            var bytes = Encoding.UTF8.GetBytes(s);
            int n = bytes.Length;
            if (n < 32) Byte(0xa0 + n);
            else if (n <= 0xff) { Byte(0xd9); Be((ulong)n, 1); }
            else if (n <= 0xffff) { Byte(0xda); Be((ulong)n, 2); }
            else { Byte(0xdb); Be((ulong)n, 4); }
            Raw(bytes);
        }

        public void WriteBin(byte[] b)
        {
            int n = b.Length;
            if (n <= 0xff) { Byte(0xc4); Be((ulong)n, 1); }
            else if (n <= 0xffff) { Byte(0xc5); Be((ulong)n, 2); }
            else { Byte(0xc6); Be((ulong)n, 4); }
            Raw(b);
        }

        private void Raw(byte[] b)
        {
            Room(b.Length);
            Buffer.BlockCopy(b, 0, _buf, _len, b.Length);
            _len += b.Length;
        }
    }
}
