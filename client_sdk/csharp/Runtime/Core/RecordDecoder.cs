// The v2 record decoder that allocates nothing once warm: every announced avatar has
// one AvatarState, updated in place by each record (the record format and the delta
// rule are Records.cs's head), and joint rotations and positions are rebuilt into
// the state's own arrays. Records.Decode (immutable Recon values) runs the same
// per-record code, so the proto vectors check both; Tests~/AllocTests.cs counts the
// bytes allocated by 16 avatars x 600 messages (none after the first few).

using System;
using System.Collections.Generic;

namespace Posecast.Client
{
    /// <summary>One avatar as this client rebuilt it: the reference the next delta applies to,
    /// and (after Rebuild) its world rotations and joint positions. Mutated by every record.</summary>
    public sealed class AvatarState
    {
        public long AvatarId { get; internal set; }
        /// <summary>A keyframe was decoded since the announce (or the last DropReferences): deltas apply.</summary>
        public bool HasReference;
        public long Seq;
        public long RootX, RootY, RootZ;                                              // 0.1 mm
        public readonly Quat[] Items = new Quat[Protocol.NumJoints];                  // PELVIS world, then local
        public readonly long[] StepRoot = new long[3];
        public readonly long[] StepRot = new long[Protocol.NumJoints * 3];
        /// <summary>The last record's flags.</summary>
        public bool Keyframe, ReachLimited;
        /// <summary>The 18 bone offsets SPINE..RIGHT_TOE from their parents, metres (the announced skeleton).</summary>
        public readonly Vec3[] Offsets = new Vec3[Protocol.NumJoints - 1];
        /// <summary>World rotations and joint positions, joint order, as of the last Rebuild.</summary>
        public readonly Quat[] World = new Quat[Protocol.NumJoints];
        public readonly Vec3[] Positions = new Vec3[Protocol.NumJoints];

        /// <summary>The PELVIS world position, metres.</summary>
        public Vec3 Root { get { return new Vec3(RootX * Records.RootUnitM, RootY * Records.RootUnitM, RootZ * Records.RootUnitM); } }

        /// <summary>World rotations and FK positions from Items, Root and Offsets, into World and Positions.</summary>
        public void Rebuild()
        {
            Records.ItemsToWorld(Items, World);
            Records.Positions(Root, World, Offsets, Positions);
        }

        /// <summary>An immutable copy of the reference.</summary>
        public Recon ToRecon()
        {
            return new Recon(Seq, RootX, RootY, RootZ, (Quat[])Items.Clone(), (long[])StepRoot.Clone(), (long[])StepRot.Clone());
        }

        /// <summary>Take `r` as the reference (null: none yet).</summary>
        public void SetReference(Recon r)
        {
            HasReference = r != null;
            if (r == null) return;
            Seq = r.Seq; RootX = r.RootX; RootY = r.RootY; RootZ = r.RootZ;
            Array.Copy(r.Items, Items, Items.Length);
            Array.Copy(r.StepRoot, StepRoot, StepRoot.Length);
            Array.Copy(r.StepRot, StepRot, StepRot.Length);
        }
    }

    /// <summary>Told of each record as it is decoded (the state is reused: copy what you keep).</summary>
    public interface IRecordSink
    {
        void Record(AvatarState avatar);
    }

    /// <summary>Every announced avatar's state, by avatar id, and the decoder of a poses message's records.</summary>
    public sealed class RecordDecoder
    {
        private readonly Dictionary<long, AvatarState> _avatars = new Dictionary<long, AvatarState>();
        private readonly Stack<AvatarState> _spare = new Stack<AvatarState>();
        private readonly long[] _residuals = new long[(Protocol.NumJoints + 1) * 3];

        public int Count { get { return _avatars.Count; } }

        /// <summary>The avatar of `avatarId`, or null when it was never announced.</summary>
        public AvatarState Get(long avatarId)
        {
            AvatarState s;
            return _avatars.TryGetValue(avatarId, out s) ? s : null;
        }

        /// <summary>
        /// An avatar announced (presence join, welcome member) or re-announced (a skeleton
        /// message) with its 108-byte skeleton. `fresh`: a new avatar on this avatar id, whose
        /// first record must be a keyframe; otherwise only the skeleton changes.
        /// </summary>
        public AvatarState Announce(long avatarId, byte[] skeleton, bool fresh)
        {
            AvatarState s;
            if (!_avatars.TryGetValue(avatarId, out s))
            {
                s = _spare.Count > 0 ? _spare.Pop() : new AvatarState();
                s.AvatarId = avatarId;
                _avatars[avatarId] = s;
                fresh = true;
            }
            if (fresh) s.HasReference = false;
            Records.BytesToSkeleton(skeleton, s.Offsets);
            return s;
        }

        public void Forget(long avatarId)
        {
            AvatarState s;
            if (_avatars.TryGetValue(avatarId, out s)) { _avatars.Remove(avatarId); _spare.Push(s); }
        }

        public void Clear()
        {
            foreach (var kv in _avatars) _spare.Push(kv.Value);
            _avatars.Clear();
        }

        /// <summary>Every avatar waits for a keyframe (after a record stream that did not decode).</summary>
        public void DropReferences()
        {
            foreach (var kv in _avatars) kv.Value.HasReference = false;
        }

        /// <summary>
        /// Decode every record of data[offset, offset + count) in place, telling `sink` of each
        /// (null: nobody); returns how many. BAD_FIELD (field "data") for a malformed record, an
        /// unknown avatar id or a delta without a reference: the states before it are updated,
        /// the rest are not (call DropReferences).
        /// </summary>
        public int Decode(byte[] data, int offset, int count, IRecordSink sink)
        {
            int pos = offset, end = offset + count, n = 0;
            while (pos < end)
            {
                long avatarId = Records.ReadLeb128(data, end, ref pos);
                AvatarState s;
                if (!_avatars.TryGetValue(avatarId, out s)) throw Records.BadData("a record for avatar id " + avatarId + ", never announced");
                Step(data, end, ref pos, s, _residuals);
                n++;
                if (sink != null) sink.Record(s);
            }
            return n;
        }

        /// <summary>One record's body (after its avatar id) applied to `s`.</summary>
        internal static void Step(byte[] data, int end, ref int pos, AvatarState s, long[] res)
        {
            if (pos >= end) throw Records.BadData("a record is cut short");
            int flags = data[pos];
            if ((flags & ~Records.FlagsKnown) != 0) throw Records.BadData("a record has reserved flag bits set");
            if ((flags & Records.FlagKeyframe) != 0) ReadKeyframe(data, end, ref pos, s);
            else
            {
                if (!s.HasReference) throw Records.BadData("a delta for avatar id " + s.AvatarId + " without a keyframe");
                ReadDelta(data, end, ref pos, s, res);
            }
            s.Keyframe = (flags & Records.FlagKeyframe) != 0;
            s.ReachLimited = (flags & Records.FlagReachLimited) != 0;
        }

        private static void ReadKeyframe(byte[] data, int end, ref int pos, AvatarState s)
        {
            if (end - (pos + 1) < Records.KeyframeBytes - 1) throw Records.BadData("a keyframe is cut short");
            int at = pos + 1;
            long seq = (uint)(data[at] | data[at + 1] << 8 | data[at + 2] << 16 | data[at + 3] << 24);
            long rx = I32(data, at + 4), ry = I32(data, at + 8), rz = I32(data, at + 12);
            if (Math.Max(Math.Abs(rx), Math.Max(Math.Abs(ry), Math.Abs(rz))) > Records.RootMax)
                throw Records.BadData("a keyframe root is beyond +-1000 m");
            for (int j = 0; j < Protocol.NumJoints; j++) s.Items[j] = Records.Smallest3(data, at + 16 + 6 * j);
            s.Seq = seq; s.RootX = rx; s.RootY = ry; s.RootZ = rz;
            Array.Clear(s.StepRoot, 0, s.StepRoot.Length);
            Array.Clear(s.StepRot, 0, s.StepRot.Length);
            s.HasReference = true;
            pos += Records.KeyframeBytes;
        }

        private static long I32(byte[] d, int at) { return (int)(d[at] | d[at + 1] << 8 | d[at + 2] << 16 | d[at + 3] << 24); }

        private static void ReadDelta(byte[] data, int end, ref int pos, AvatarState s, long[] res)
        {
            pos += 1; // the flags
            if (pos >= end || data[pos] == 0) throw Records.BadData("a delta's seq step is missing or 0");
            long seq = (s.Seq + data[pos]) & Protocol.UInt32Max;
            pos += 1;
            var bits = new BitReader(data, pos, end);
            for (int item = 0; item <= Protocol.NumJoints; item++)
            {
                int w = (item == 0 ? Records.RootWidths : Records.RotWidths)[bits.Read(2)];
                for (int c = 0; c < 3; c++) res[3 * item + c] = w == 0 ? 0 : bits.ReadSigned(w);
            }
            if (bits.Overrun) throw Records.BadData("a delta is cut short");
            long sx = s.StepRoot[0] + res[0], sy = s.StepRoot[1] + res[1], sz = s.StepRoot[2] + res[2];
            long rx = s.RootX + sx, ry = s.RootY + sy, rz = s.RootZ + sz;
            if (Math.Max(Math.Abs(rx), Math.Max(Math.Abs(ry), Math.Abs(rz))) > Records.RootMax)
                throw Records.BadData("a delta takes the root beyond +-1000 m");
            // Checked: nothing below throws, so a refused delta leaves the state as it was.
            pos += (bits.Count + 7) / 8;
            s.Seq = seq;
            s.StepRoot[0] = sx; s.StepRoot[1] = sy; s.StepRoot[2] = sz;
            s.RootX = rx; s.RootY = ry; s.RootZ = rz;
            const double k = Records.RotStepRad;
            for (int j = 0; j < Protocol.NumJoints; j++)
            {
                long v0 = s.StepRot[3 * j], v1 = s.StepRot[3 * j + 1], v2 = s.StepRot[3 * j + 2];
                long e0 = res[3 + 3 * j], e1 = res[4 + 3 * j], e2 = res[5 + 3 * j];
                s.StepRot[3 * j] = v0 + e0; s.StepRot[3 * j + 1] = v1 + e1; s.StepRot[3 * j + 2] = v2 + e2;
                var pred = s.Items[j] * Quat.FromRotationVector(v0 * k, v1 * k, v2 * k);
                s.Items[j] = (pred * Quat.FromRotationVector(e0 * k, e1 * k, e2 * k)).Normalised;
            }
        }

        /// <summary>Little-endian bits (bit n is bit n % 8 of byte n / 8); zeros past the end.</summary>
        private struct BitReader
        {
            private readonly byte[] _d;
            private readonly int _start, _end;
            public int Count;

            public BitReader(byte[] d, int start, int end) { _d = d; _start = start; _end = end; Count = 0; }

            public bool Overrun { get { return Count > 8 * (_end - _start); } }

            public int Read(int w)
            {
                int v = 0;
                for (int i = 0; i < w; i++)
                {
                    int n = Count + i;
                    int at = _start + (n >> 3);
                    if (at < _end && (_d[at] >> (n & 7) & 1) != 0) v |= 1 << i;
                }
                Count += w;
                return v;
            }

            public long ReadSigned(int w)
            {
                int v = Read(w);
                return (v >> (w - 1) & 1) != 0 ? v - (1 << w) : v;
            }
        }
    }
}
