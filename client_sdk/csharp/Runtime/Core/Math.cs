// Vectors and quaternions in double precision (the wire's precision; Unity's float
// types are converted at the Unity edge). Glossary as in the other SDKs: p a
// position (metres), q a quaternion xyzw with the scalar last (Hamilton product,
// rotating vectors from the object's frame into the world), a rotation vector v
// (axis times angle, radians).

using System;

namespace Posecast.Client
{
    /// <summary>A position or direction, metres in posecast's world (right-handed, +Y up).</summary>
    public struct Vec3
    {
        public double X, Y, Z;
        public Vec3(double x, double y, double z) { X = x; Y = y; Z = z; }

        public static readonly Vec3 Zero = new Vec3(0, 0, 0);
        public static Vec3 operator +(Vec3 a, Vec3 b) { return new Vec3(a.X + b.X, a.Y + b.Y, a.Z + b.Z); }
        public static Vec3 operator -(Vec3 a, Vec3 b) { return new Vec3(a.X - b.X, a.Y - b.Y, a.Z - b.Z); }
        public static Vec3 operator *(Vec3 a, double k) { return new Vec3(a.X * k, a.Y * k, a.Z * k); }
        public double Length { get { return Math.Sqrt(X * X + Y * Y + Z * Z); } }
        public bool IsFinite { get { return !double.IsNaN(X + Y + Z) && !double.IsInfinity(X + Y + Z); } }

        /// <summary>a + (b - a) * u, as numpy computes it.</summary>
        public static Vec3 Lerp(Vec3 a, Vec3 b, double u)
        {
            return new Vec3(a.X + (b.X - a.X) * u, a.Y + (b.Y - a.Y) * u, a.Z + (b.Z - a.Z) * u);
        }

        public override string ToString() { return "(" + X + ", " + Y + ", " + Z + ")"; }
    }

    /// <summary>A rotation, quaternion xyzw (scalar last).</summary>
    public struct Quat
    {
        public double X, Y, Z, W;
        public Quat(double x, double y, double z, double w) { X = x; Y = y; Z = z; W = w; }

        public static readonly Quat Identity = new Quat(0, 0, 0, 1);

        /// <summary>The Hamilton product a * b (b first, then a).</summary>
        public static Quat operator *(Quat a, Quat b)
        {
            return new Quat(
                a.W * b.X + a.X * b.W + a.Y * b.Z - a.Z * b.Y,
                a.W * b.Y - a.X * b.Z + a.Y * b.W + a.Z * b.X,
                a.W * b.Z + a.X * b.Y - a.Y * b.X + a.Z * b.W,
                a.W * b.W - a.X * b.X - a.Y * b.Y - a.Z * b.Z);
        }

        public Quat Conjugate { get { return new Quat(-X, -Y, -Z, W); } }
        public Quat Negated { get { return new Quat(-X, -Y, -Z, -W); } }
        public double Norm { get { return Math.Sqrt(X * X + Y * Y + Z * Z + W * W); } }
        public static double Dot(Quat a, Quat b) { return a.X * b.X + a.Y * b.Y + a.Z * b.Z + a.W * b.W; }

        public Quat Normalised
        {
            get { double n = Norm; return new Quat(X / n, Y / n, Z / n, W / n); }
        }

        /// <summary>The vector v rotated by this (unit) quaternion: its rotation matrix times v.</summary>
        public Vec3 Rotate(Vec3 v)
        {
            // The matrix the server's FK uses (records._quat2mat), not renormalised.
            double m00 = 1 - 2 * (Y * Y + Z * Z), m01 = 2 * (X * Y - Z * W), m02 = 2 * (X * Z + Y * W);
            double m10 = 2 * (X * Y + Z * W), m11 = 1 - 2 * (X * X + Z * Z), m12 = 2 * (Y * Z - X * W);
            double m20 = 2 * (X * Z - Y * W), m21 = 2 * (Y * Z + X * W), m22 = 1 - 2 * (X * X + Y * Y);
            return new Vec3(m00 * v.X + m01 * v.Y + m02 * v.Z,
                            m10 * v.X + m11 * v.Y + m12 * v.Z,
                            m20 * v.X + m21 * v.Y + m22 * v.Z);
        }

        /// <summary>Rotation vector (radians) to a unit quaternion: (v sin(t/2)/t, cos(t/2)).</summary>
        public static Quat FromRotationVector(double vx, double vy, double vz)
        {
            double theta = Math.Sqrt(vx * vx + vy * vy + vz * vz);
            if (!(theta > 0.0)) return Identity;
            double k = Math.Sin(theta / 2.0) / theta;
            return new Quat(vx * k, vy * k, vz * k, Math.Cos(theta / 2.0));
        }

        /// <summary>The rotation vector (radians) of a unit quaternion, the shorter way.</summary>
        public Vec3 ToRotationVector()
        {
            var q = W < 0 ? Negated : this;
            double s = Math.Sqrt(q.X * q.X + q.Y * q.Y + q.Z * q.Z);
            if (!(s > 0.0)) return Vec3.Zero;
            double theta = 2.0 * Math.Atan2(s, q.W);
            double k = theta / s;
            return new Vec3(q.X * k, q.Y * k, q.Z * k);
        }

        /// <summary>
        /// Spherical interpolation on the shorter arc; u outside [0, 1] extrapolates along
        /// the same great circle. Inputs need not be unit (the SDKs' quat_slerp).
        /// </summary>
        public static Quat Slerp(Quat q0, Quat q1, double u)
        {
            var a = q0.Normalised;
            var b = q1.Normalised;
            double dot = Dot(a, b);
            if (dot < 0.0) { b = b.Negated; }
            double cos = Math.Min(Math.Abs(dot), 1.0);
            double omega = Math.Acos(cos);
            double sin = Math.Sin(omega);
            double w0, w1;
            if (sin < 1e-6) { w0 = 1.0 - u; w1 = u; }
            else { w0 = Math.Sin((1.0 - u) * omega) / sin; w1 = Math.Sin(u * omega) / sin; }
            var o = new Quat(w0 * a.X + w1 * b.X, w0 * a.Y + w1 * b.Y, w0 * a.Z + w1 * b.Z, w0 * a.W + w1 * b.W);
            return o.Normalised;
        }

        /// <summary>The angle between two rotations, radians (q and -q are the same).</summary>
        public static double Angle(Quat a, Quat b)
        {
            var rel = a.Normalised.Conjugate * b.Normalised;
            return rel.ToRotationVector().Length;
        }

        public override string ToString() { return "(" + X + ", " + Y + ", " + Z + ", " + W + ")"; }
    }
}
