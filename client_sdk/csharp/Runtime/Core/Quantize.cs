// v1 pose quantisation: millimetre offsets and snorm16 quaternions (proto/README.md,
// "pose"). pos_mm holds 18 x 3 int16 LE millimetres of (joint - root) for SPINE ..
// RIGHT_TOE; rot holds 19 x 4 int16 LE round(q * 32767), not renormalised on decode.

using System;

namespace Posecast.Client
{
    public static class Quantize
    {
        public const double PosUnitM = 0.001;
        public const double RotScale = 32767.0;
        public const int PosBytes = (Protocol.NumJoints - 1) * 3 * 2; // 108
        public const int RotBytes = Protocol.NumJoints * 4 * 2;       // 152

        internal static short I16(byte[] b, int at) { return (short)(b[at] | (b[at + 1] << 8)); }

        private static void PutI16(byte[] b, int at, long v) { b[at] = (byte)v; b[at + 1] = (byte)(v >> 8); }

        /// <summary>(root, 108 offset bytes) to 19 world positions, metres.</summary>
        public static Vec3[] Mm2Pos(Vec3 root, byte[] blob)
        {
            var out_ = new Vec3[Protocol.NumJoints];
            out_[0] = root;
            for (int j = 1; j < Protocol.NumJoints; j++)
            {
                int at = (j - 1) * 6;
                out_[j] = new Vec3(I16(blob, at) * PosUnitM + root.X, I16(blob, at + 2) * PosUnitM + root.Y,
                                   I16(blob, at + 4) * PosUnitM + root.Z);
            }
            return out_;
        }

        /// <summary>19 world positions to the 108 offset bytes (OUT_OF_RANGE beyond 32.767 m).</summary>
        public static byte[] Pos2Mm(Vec3[] p)
        {
            var root = p[0];
            var b = new byte[PosBytes];
            for (int j = 1; j < Protocol.NumJoints; j++)
            {
                double[] d = { (p[j].X - root.X) / PosUnitM, (p[j].Y - root.Y) / PosUnitM, (p[j].Z - root.Z) / PosUnitM };
                for (int k = 0; k < 3; k++)
                {
                    double r = Math.Round(d[k], MidpointRounding.ToEven);
                    if (!(Math.Abs(r) <= 32767)) throw ErrorCodes.OutOfRange("pos_mm", "a joint is more than 32.767 m from the pelvis");
                    PutI16(b, (j - 1) * 6 + 2 * k, (long)r);
                }
            }
            return b;
        }

        /// <summary>152 bytes to 19 quaternions xyzw (not renormalised; NOT_NORMALISED off 1e-3).</summary>
        public static Quat[] Snorm2Quat(byte[] blob)
        {
            var q = new Quat[Protocol.NumJoints];
            for (int j = 0; j < Protocol.NumJoints; j++)
            {
                int at = j * 8;
                q[j] = new Quat(I16(blob, at) / RotScale, I16(blob, at + 2) / RotScale,
                                I16(blob, at + 4) / RotScale, I16(blob, at + 6) / RotScale);
                double n = q[j].Norm;
                if (!(Math.Abs(n - 1.0) <= Protocol.QuatTolerance))
                    throw ErrorCodes.NotNormalised("rot", "rotation of joint " + j + " has norm " + n);
            }
            return q;
        }

        /// <summary>19 unit quaternions to 152 bytes of snorm16.</summary>
        public static byte[] Quat2Snorm(Quat[] q)
        {
            var b = new byte[RotBytes];
            for (int j = 0; j < Protocol.NumJoints; j++)
            {
                double[] c = { q[j].X, q[j].Y, q[j].Z, q[j].W };
                for (int k = 0; k < 4; k++)
                {
                    double r = Math.Round(c[k] * RotScale, MidpointRounding.ToEven);
                    if (!(Math.Abs(r) <= 32767)) throw ErrorCodes.NotNormalised("rot", "a rotation is not a unit quaternion");
                    PutI16(b, j * 8 + 2 * k, (long)r);
                }
            }
            return b;
        }
    }
}
