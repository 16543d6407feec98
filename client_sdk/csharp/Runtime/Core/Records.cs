// Protocol v2 pose records: the decoder of a poses message's data (pure: bytes in,
// avatar states out), after server/posecast/online/protocol/records.py.
//
// A record describes one avatar by 19 items (the PELVIS world rotation, then the 18
// local joint rotations in joint order) plus the PELVIS world position (the root):
//
//   record   = avatar id (LEB128) | flags (u8) | keyframe body | delta body
//   keyframe = seq (u32 LE) | root (3 x i32 LE, 0.1 mm) | 19 x smallest-three (48 bits)
//   delta    = seq step (u8, 1..255) | bitstream: the root item, then the 19 rotation
//              items, each a 2-bit width class and, unless the class is 0, 3 signed
//              components of that width
//
// A delta is relative to the reference, the state this client rebuilt from the
// previous record of that avatar. Per item it keeps the last step v (3 ints, zero
// after a keyframe); a delta's residual r gives the new step d = v + r and
//
//   root  <- root + d                                           (0.1 mm)
//   rot_i <- normalise(rot_i * exp(v * STEP) * exp(r * STEP))    (rotation vectors)
//
// Every malformed record is BAD_FIELD with field "data". The per-record code is
// RecordDecoder's (in place, allocation-free); Decode here wraps it in immutable Recons.

using System;
using System.Collections.Generic;

namespace Posecast.Client
{
    /// <summary>What a client holds for one avatar after a record (never mutated).</summary>
    public sealed class Recon
    {
        public readonly long Seq;
        public readonly long RootX, RootY, RootZ;      // 0.1 mm
        public readonly Quat[] Items;                  // 19: PELVIS world, then local rotations
        public readonly long[] StepRoot;               // 3: the last step of the root
        public readonly long[] StepRot;                // 19 x 3: the last step of each rotation

        public Recon(long seq, long rx, long ry, long rz, Quat[] items, long[] stepRoot, long[] stepRot)
        {
            Seq = seq; RootX = rx; RootY = ry; RootZ = rz; Items = items; StepRoot = stepRoot; StepRot = stepRot;
        }

        /// <summary>The PELVIS world position, metres.</summary>
        public Vec3 Root
        {
            get { return new Vec3(RootX * Records.RootUnitM, RootY * Records.RootUnitM, RootZ * Records.RootUnitM); }
        }
    }

    /// <summary>One decoded record: whose (AvatarId), which kind, and the new state.</summary>
    public struct Record
    {
        public long AvatarId;
        public bool Keyframe;
        public bool ReachLimited;
        public Recon Recon;
    }

    public static class Records
    {
        public const double RootUnitM = 1e-4;        // one step of the root (0.1 mm)
        public const double SkeletonUnitM = 1e-4;    // one step of a skeleton bone offset
        public const int SkeletonBytes = (Protocol.NumJoints - 1) * 3 * 2; // 108
        public const double Smallest3Scale = 23168.0;
        public const double RotStepRad = 1.0 / 512.0; // 2^-9 rad
        public static readonly int[] RotWidths = { 0, 4, 7, 12 };
        public static readonly int[] RootWidths = { 0, 5, 8, 14 };
        public const int FlagKeyframe = 0x01;
        public const int FlagReachLimited = 0x02;
        public const int FlagsKnown = FlagKeyframe | FlagReachLimited;
        public const int KeyframeBytes = 1 + 4 + 12 + Protocol.NumJoints * 6; // 131, after the avatar id
        public const long MaxAvatarId = Protocol.UInt32Max;
        internal const long RootMax = 10000000; // 1000 m in 0.1 mm

        private static ProtocolException Bad(string m) { return ErrorCodes.BadField("data", m); }
        internal static ProtocolException BadData(string m) { return Bad(m); }

        // --- skeletons -----------------------------------------------------------------

        /// <summary>108 bytes to the 18 bone offsets SPINE..RIGHT_TOE from their parents, metres.</summary>
        public static Vec3[] BytesToSkeleton(byte[] blob)
        {
            return BytesToSkeleton(blob, new Vec3[Protocol.NumJoints - 1]);
        }

        /// <summary>BytesToSkeleton into `into` (18 offsets); returns it.</summary>
        public static Vec3[] BytesToSkeleton(byte[] blob, Vec3[] into)
        {
            for (int j = 0; j < Protocol.NumJoints - 1; j++)
                into[j] = new Vec3(Quantize.I16(blob, 6 * j) * SkeletonUnitM, Quantize.I16(blob, 6 * j + 2) * SkeletonUnitM,
                                   Quantize.I16(blob, 6 * j + 4) * SkeletonUnitM);
            return into;
        }

        // --- LEB128 avatar ids ---------------------------------------------------------

        /// <summary>An unsigned LEB128 at pos (at most 5 bytes, minimal, at most 2^32 - 1).</summary>
        public static long ReadLeb128(byte[] data, int end, ref int pos)
        {
            long value = 0;
            int shift = 0;
            for (int k = 0; k < 5; k++)
            {
                if (pos + k >= end) throw Bad("a record is cut short in its avatar id");
                int b = data[pos + k];
                value |= (long)(b & 0x7f) << shift;
                shift += 7;
                if ((b & 0x80) == 0)
                {
                    if (value > MaxAvatarId || (k > 0 && b == 0)) throw Bad("an avatar id is too large or not minimal");
                    pos += k + 1;
                    return value;
                }
            }
            throw Bad("an avatar id is longer than 5 bytes");
        }

        // --- smallest-three -------------------------------------------------------------

        /// <summary>
        /// One 48-bit little-endian word: three 15-bit two's-complement components (the
        /// quaternion without its largest one, xyzw order, times 23168) from bit 0, the
        /// dropped component's index at bits 45-46, bit 47 zero.
        /// </summary>
        public static Quat Smallest3(byte[] b, int at)
        {
            ulong word = 0;
            for (int i = 5; i >= 0; i--) word = (word << 8) | b[at + i];
            if ((word >> 47) != 0) throw Bad("a keyframe rotation has its reserved bit set");
            int k = (int)(word >> 45 & 3);
            double a0 = Comp15(word, 0), a1 = Comp15(word, 1), a2 = Comp15(word, 2);
            double big = Math.Sqrt(Math.Max(0.0, 1.0 - (a0 * a0 + a1 * a1 + a2 * a2)));
            switch (k)
            {
                case 0: return new Quat(big, a0, a1, a2);
                case 1: return new Quat(a0, big, a1, a2);
                case 2: return new Quat(a0, a1, big, a2);
                default: return new Quat(a0, a1, a2, big);
            }
        }

        private static double Comp15(ulong word, int n)
        {
            int bits = (int)(word >> (15 * n) & 0x7fff);
            return ((bits & 0x4000) != 0 ? bits - 0x8000 : bits) / Smallest3Scale;
        }

        // --- records --------------------------------------------------------------------

        /// <summary>
        /// Every record of a poses.data blob, against refs (avatar id to the last state; a null
        /// value for an announced avatar without one yet). Updates refs as it goes.
        /// BAD_FIELD (field "data") for a malformed record, an unknown avatar id or a delta
        /// without a reference. (RecordDecoder does the same in place, allocating nothing.)
        /// </summary>
        public static List<Record> Decode(byte[] data, IDictionary<long, Recon> refs)
        {
            var out_ = new List<Record>();
            var state = new AvatarState();
            var residuals = new long[(Protocol.NumJoints + 1) * 3];
            int pos = 0, end = data.Length;
            while (pos < end)
            {
                long avatarId = ReadLeb128(data, end, ref pos);
                Recon ref_;
                if (!refs.TryGetValue(avatarId, out ref_)) throw Bad("a record for avatar id " + avatarId + ", never announced");
                state.AvatarId = avatarId;
                state.SetReference(ref_);
                RecordDecoder.Step(data, end, ref pos, state, residuals);
                var recon = state.ToRecon();
                refs[avatarId] = recon;
                out_.Add(new Record { AvatarId = avatarId, Keyframe = state.Keyframe, ReachLimited = state.ReachLimited, Recon = recon });
            }
            return out_;
        }

        // --- rotations and FK ------------------------------------------------------------

        /// <summary>Items (PELVIS world, then local rotations) to world rotations, parents first.</summary>
        public static Quat[] ItemsToWorld(Quat[] items) { return ItemsToWorld(items, new Quat[Protocol.NumJoints]); }

        /// <summary>ItemsToWorld into `world` (19); returns it.</summary>
        public static Quat[] ItemsToWorld(Quat[] items, Quat[] world)
        {
            world[0] = items[0];
            for (int j = 1; j < Protocol.NumJoints; j++) world[j] = world[Protocol.Parents[j]] * items[j];
            return world;
        }

        /// <summary>World rotations to items: each joint's rotation relative to its parent.</summary>
        public static Quat[] WorldToItems(Quat[] world)
        {
            var items = new Quat[Protocol.NumJoints];
            items[0] = world[0];
            for (int j = 1; j < Protocol.NumJoints; j++) items[j] = world[Protocol.Parents[j]].Conjugate * world[j];
            return items;
        }

        /// <summary>Joint positions by FK: p[j] = p[parent] + R(world[parent]) offsets[j - 1].</summary>
        public static Vec3[] Positions(Vec3 root, Quat[] world, Vec3[] offsets)
        {
            return Positions(root, world, offsets, new Vec3[Protocol.NumJoints]);
        }

        /// <summary>Positions into `p` (19); returns it.</summary>
        public static Vec3[] Positions(Vec3 root, Quat[] world, Vec3[] offsets, Vec3[] p)
        {
            p[0] = root;
            for (int j = 1; j < Protocol.NumJoints; j++)
            {
                int parent = Protocol.Parents[j];
                p[j] = p[parent] + world[parent].Rotate(offsets[j - 1]);
            }
            return p;
        }
    }
}
