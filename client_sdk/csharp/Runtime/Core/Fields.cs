// Field validators for the decoder: one msgpack value in, a checked value out.
//
// Each takes the message map, the key, the value's bounds and `at` (a path prefix for
// nested maps such as "members[3]."), and throws the error the spec names:
// BAD_FIELD for a missing field or a wrong type, shape or value; OUT_OF_RANGE for a
// number outside its range (NaN and infinities included) or a string of the wrong
// byte length; NOT_NORMALISED for a quaternion off unit length. nil is absent.

using System;
using System.Collections.Generic;

namespace Posecast.Client
{
    internal static class Fields
    {
        // | |q| - 1 | <= tolerance, compared on the squared norm (as the server does).
        private static readonly double Norm2Lo = (1.0 - Protocol.QuatTolerance) * (1.0 - Protocol.QuatTolerance);
        private static readonly double Norm2Hi = (1.0 + Protocol.QuatTolerance) * (1.0 + Protocol.QuatTolerance);

        public static bool Has(MsgValue m, string key)
        {
            var v = m.Get(key);
            return v != null && v.Kind != MsgKind.Nil;
        }

        private static MsgValue Need(MsgValue m, string key, string at)
        {
            var v = m.Get(key);
            if (v == null || v.Kind == MsgKind.Nil)
                throw ErrorCodes.BadField(at + key, "missing field " + at + key);
            return v;
        }

        private static ProtocolException Bad(string path, string expected)
        {
            return ErrorCodes.BadField(path, path + ": expected " + expected);
        }

        public static long Int(MsgValue m, string key, long lo, long hi, string at = "")
        {
            var v = Need(m, key, at);
            if (v.Kind != MsgKind.Int) throw Bad(at + key, "an integer");
            if (v.IsHugeUInt || v.Int < lo || v.Int > hi)
                throw ErrorCodes.OutOfRange(at + key, at + key + "=" + v + " outside [" + lo + ", " + hi + "]");
            return v.Int;
        }

        /// <summary>A number (float64, float32 or int on the wire) in [lo, hi], finite.</summary>
        public static double Float(MsgValue m, string key, double lo, double hi, string at = "")
        {
            var v = Need(m, key, at);
            if (!v.IsNumber) throw Bad(at + key, "a number");
            double d = v.AsDouble;
            if (!(lo <= d && d <= hi)) // NaN fails too
                throw ErrorCodes.OutOfRange(at + key, at + key + "=" + d + " outside [" + lo + ", " + hi + "]");
            return d;
        }

        public static bool Bool(MsgValue m, string key, string at = "")
        {
            var v = Need(m, key, at);
            if (v.Kind != MsgKind.Bool) throw Bad(at + key, "a boolean");
            return v.Bool;
        }

        /// <summary>A string of minBytes..maxBytes UTF-8 bytes.</summary>
        public static string Str(MsgValue m, string key, int maxBytes, int minBytes = 1, string at = "")
        {
            var v = Need(m, key, at);
            if (v.Kind != MsgKind.Str) throw Bad(at + key, "a string");
            int n = Utf8.ByteCount(v.Str);
            if (n < minBytes || n > maxBytes)
                throw ErrorCodes.OutOfRange(at + key, at + key + " is " + n + " bytes, not " + minBytes + ".." + maxBytes);
            return v.Str;
        }

        public static bool IsId(string s)
        {
            if (s.Length == 0) return false;
            foreach (char c in s)
            {
                bool ok = (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9')
                          || c == '_' || c == '.' || c == ':' || c == '-';
                if (!ok) return false;
            }
            return true;
        }

        /// <summary>A room name or id: 1..maxBytes of [A-Za-z0-9_.:-].</summary>
        public static string Id(MsgValue m, string key, int maxBytes, string at = "")
        {
            var s = Str(m, key, maxBytes, 1, at);
            if (!IsId(s)) throw Bad(at + key, "only A-Z a-z 0-9 _ . : -");
            return s;
        }

        public static bool HasControl(string s)
        {
            foreach (char c in s) if (c <= '\u001f' || c == '\u007f') return true;
            return false;
        }

        /// <summary>A display name: 1..maxBytes, no control characters.</summary>
        public static string Name(MsgValue m, string key, int maxBytes, string at = "")
        {
            var s = Str(m, key, maxBytes, 1, at);
            if (HasControl(s)) throw Bad(at + key, "no control characters");
            return s;
        }

        public static string Enum(MsgValue m, string key, string[] options, string at = "")
        {
            var v = Need(m, key, at);
            if (v.Kind != MsgKind.Str || Array.IndexOf(options, v.Str) < 0)
                throw Bad(at + key, "one of " + string.Join(", ", options));
            return v.Str;
        }

        public static List<MsgValue> List(MsgValue m, string key, int maxLen, string at = "")
        {
            var v = Need(m, key, at);
            if (v.Kind != MsgKind.Array) throw Bad(at + key, "an array");
            if (v.Items.Count > maxLen)
                throw ErrorCodes.OutOfRange(at + key, at + key + " has " + v.Items.Count + " items, max " + maxLen);
            return v.Items;
        }

        public static MsgValue Map(MsgValue m, string key, string at = "")
        {
            var v = Need(m, key, at);
            if (v.Kind != MsgKind.Map) throw Bad(at + key, "a map");
            return v;
        }

        public static byte[] Bin(MsgValue m, string key, int size, string at = "")
        {
            var v = Need(m, key, at);
            if (v.Kind != MsgKind.Bin || v.Bin.Length != size) throw Bad(at + key, "bin of " + size + " bytes");
            return v.Bin;
        }

        /// <summary>A world position [x, y, z] in metres, each within +-1000.</summary>
        public static Vec3 Point(MsgValue m, string key, string at = "")
        {
            var v = Need(m, key, at);
            string path = at + key;
            if (v.Kind != MsgKind.Array || v.Items.Count != 3 || !v.Items.TrueForAll(x => x.IsNumber))
                throw Bad(path, "an array of 3 numbers");
            double x0 = v.Items[0].AsDouble, y0 = v.Items[1].AsDouble, z0 = v.Items[2].AsDouble;
            if (!(Math.Abs(x0) <= Protocol.MaxCoordM && Math.Abs(y0) <= Protocol.MaxCoordM && Math.Abs(z0) <= Protocol.MaxCoordM))
                throw ErrorCodes.OutOfRange(path, path + " outside +-1000 m or not finite");
            return new Vec3(x0, y0, z0);
        }

        /// <summary>
        /// 4 trackers [px, py, pz, qx, qy, qz, qw]. Slots whose valid bit is clear are only
        /// type-checked and come back as the origin with the identity rotation; the others'
        /// quaternions are renormalised exactly as the spec says.
        /// </summary>
        public static void Trackers(MsgValue m, string key, int valid, out Vec3[] pos, out Quat[] quat)
        {
            var rows = Need(m, key, "");
            if (rows.Kind != MsgKind.Array || rows.Items.Count != Protocol.NumTrackers)
                throw Bad(key, "an array of 4 trackers");
            Rows(rows, key, valid, out pos, out quat);
        }

        /// <summary>
        /// A tracker set's 1 to 10 rows, checked as Trackers checks trackers, with `valid`
        /// (null: all) a bit mask over them (bits beyond the rows: OUT_OF_RANGE, field valid).
        /// Returns the mask in force.
        /// </summary>
        public static int Sites(MsgValue m, string key, int? valid, out Vec3[] pos, out Quat[] quat)
        {
            var rows = Need(m, key, "");
            if (rows.Kind != MsgKind.Array || rows.Items.Count < 1 || rows.Items.Count > TrackerSet.MaxSites)
                throw Bad(key, "an array of 1 to " + TrackerSet.MaxSites + " sites");
            int full = (1 << rows.Items.Count) - 1;
            if (valid.HasValue && valid.Value > full)
                throw ErrorCodes.OutOfRange("valid", "valid " + valid.Value + " has bits beyond the " + rows.Items.Count + " sites");
            int mask = valid ?? full;
            Rows(rows, key, mask, out pos, out quat);
            return mask;
        }

        private static void Rows(MsgValue rows, string key, int valid, out Vec3[] pos, out Quat[] quat)
        {
            int count = rows.Items.Count;
            pos = new Vec3[count];
            quat = new Quat[count];
            for (int i = 0; i < count; i++)
            {
                var row = rows.Items[i];
                string path = key + "[" + i + "]";
                if (row.Kind != MsgKind.Array || row.Items.Count != 7 || !row.Items.TrueForAll(x => x.IsNumber))
                    throw Bad(path, "an array of 7 numbers");
                if ((valid >> i & 1) == 0)
                {
                    pos[i] = Vec3.Zero;
                    quat[i] = Quat.Identity;
                    continue;
                }
                double px = row.Items[0].AsDouble, py = row.Items[1].AsDouble, pz = row.Items[2].AsDouble;
                double qx = row.Items[3].AsDouble, qy = row.Items[4].AsDouble, qz = row.Items[5].AsDouble, qw = row.Items[6].AsDouble;
                if (!(Math.Abs(px) <= Protocol.MaxCoordM && Math.Abs(py) <= Protocol.MaxCoordM && Math.Abs(pz) <= Protocol.MaxCoordM))
                    throw ErrorCodes.OutOfRange(path, path + " position outside +-1000 m or not finite");
                double n2 = qx * qx + qy * qy + qz * qz + qw * qw;
                if (!(Norm2Lo <= n2 && n2 <= Norm2Hi))
                {
                    if (!(IsFinite(qx) && IsFinite(qy) && IsFinite(qz) && IsFinite(qw)))
                        throw ErrorCodes.OutOfRange(path, path + " orientation not finite");
                    throw ErrorCodes.NotNormalised(path, path + " orientation has norm " + Math.Sqrt(n2));
                }
                double n = Math.Sqrt(n2);
                pos[i] = new Vec3(px, py, pz);
                quat[i] = new Quat(qx / n, qy / n, qz / n, qw / n);
            }
        }

        public static bool IsFinite(double d) { return !double.IsNaN(d) && !double.IsInfinity(d); }
    }
}
