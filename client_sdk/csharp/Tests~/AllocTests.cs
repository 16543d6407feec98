// No steady-state allocation: 16 remote players x 600 poses messages (10 s at 60 Hz,
// a keyframe per player per second, deltas between) decoded in place by RecordDecoder,
// FK into the avatar's state, and each record driving a PosecastAvatarDriver's bones
// (the stand-in UnityEngine's Transforms). After a warm-up of 60 messages the bytes
// allocated on this thread (GC.GetAllocatedBytesForCurrentThread) must be 0. A control
// run of the allocating API (Records.Decode) shows the counter counts. The manager's
// path through the jitter buffer (events fed, each avatar's pose sampled into a buffer
// of its own, the bones posed) must allocate 0 bytes after the warm-up too.

using System;
using System.Collections.Generic;
using Posecast.Client.Unity;
using UnityEngine;

namespace Posecast.Client.Tests
{
    /// <summary>A test-side v2 record writer (keyframes and deltas), enough to make streams.</summary>
    public sealed class RecordWriter
    {
        private readonly List<byte> _out = new List<byte>();
        private int _bits, _nbits;

        public byte[] Take() { var b = _out.ToArray(); _out.Clear(); return b; }

        private void Leb128(long v)
        {
            do { byte b = (byte)(v & 0x7f); v >>= 7; _out.Add(v != 0 ? (byte)(b | 0x80) : b); } while (v != 0);
        }

        private void U32(long v) { for (int i = 0; i < 4; i++) _out.Add((byte)(v >> (8 * i))); }

        public void Keyframe(long avatarId, long seq, long rx, long ry, long rz, Quat[] items, bool reachLimited = false)
        {
            Leb128(avatarId);
            _out.Add((byte)(Records.FlagKeyframe | (reachLimited ? Records.FlagReachLimited : 0)));
            U32(seq); U32(rx); U32(ry); U32(rz);
            foreach (var q in items) Smallest3(q);
        }

        private void Smallest3(Quat q)
        {
            var c = new[] { q.X, q.Y, q.Z, q.W };
            int k = 0;
            for (int i = 1; i < 4; i++) if (Math.Abs(c[i]) > Math.Abs(c[k])) k = i;
            double sign = c[k] < 0 ? -1 : 1;
            ulong word = (ulong)k << 45;
            int n = 0;
            for (int i = 0; i < 4; i++)
            {
                if (i == k) continue;
                long v = (long)Math.Round(c[i] * sign * Records.Smallest3Scale);
                word |= ((ulong)v & 0x7fff) << (15 * n++);
            }
            for (int i = 0; i < 6; i++) _out.Add((byte)(word >> (8 * i)));
        }

        /// <summary>A delta: residuals of the root (3) then the 19 rotations (3 each), in steps.</summary>
        public void Delta(long avatarId, int seqStep, long[] residuals)
        {
            Leb128(avatarId);
            _out.Add(0);
            _out.Add((byte)seqStep);
            _bits = 0; _nbits = 0;
            for (int item = 0; item <= Protocol.NumJoints; item++)
            {
                var widths = item == 0 ? Records.RootWidths : Records.RotWidths;
                int cls = 0;
                for (int c = 0; c < 3; c++)
                {
                    long r = residuals[3 * item + c];
                    while (r != 0 && (cls == 0 || r < -(1L << (widths[cls] - 1)) || r >= 1L << (widths[cls] - 1))) cls++;
                }
                if (cls > 3) throw new ArgumentException("a residual too large for a delta");
                Bits(cls, 2);
                if (widths[cls] > 0) for (int c = 0; c < 3; c++) Bits(residuals[3 * item + c], widths[cls]);
            }
            if (_nbits > 0) _out.Add((byte)_bits);
        }

        private void Bits(long v, int w)
        {
            for (int i = 0; i < w; i++)
            {
                if ((v >> i & 1) != 0) _bits |= 1 << _nbits;
                if (++_nbits == 8) { _out.Add((byte)_bits); _bits = 0; _nbits = 0; }
            }
        }
    }

    public static class AllocTests
    {
        public const int Players = 16, Messages = 600, WarmUp = 60;

        /// <summary>The reference skeleton as a skeleton blob (108 bytes, 0.1 mm).</summary>
        public static byte[] SkeletonBlob()
        {
            var blob = new byte[Records.SkeletonBytes];
            var off = Skeleton.ReferenceOffsets();
            for (int j = 0; j < off.Length; j++)
            {
                var v = new[] { off[j].X, off[j].Y, off[j].Z };
                for (int c = 0; c < 3; c++)
                {
                    short s = (short)Math.Round(v[c] / Records.SkeletonUnitM);
                    blob[6 * j + 2 * c] = (byte)s; blob[6 * j + 2 * c + 1] = (byte)(s >> 8);
                }
            }
            return blob;
        }

        /// <summary>16 players walking in place with small random turns: one poses.data per tick.</summary>
        public static List<byte[]> Stream(int seed)
        {
            var rng = new Random(seed);
            var w = new RecordWriter();
            var stream = new List<byte[]>();
            var res = new long[(Protocol.NumJoints + 1) * 3];
            var step = new long[Players, res.Length]; // each item's last step, as the decoder keeps it
            var items = new Quat[Protocol.NumJoints];
            for (int k = 0; k < Messages; k++)
            {
                for (int p = 0; p < Players; p++)
                {
                    if ((k + 4 * p) % 60 == 0 || k == 0)
                    {
                        for (int j = 0; j < items.Length; j++)
                            items[j] = Quat.FromRotationVector(rng.NextDouble() * 0.4 - 0.2, rng.NextDouble() * 0.4 - 0.2, rng.NextDouble() * 0.4 - 0.2);
                        w.Keyframe(p + 1, 1000 * p + k, 1500 * p, 9800, 2000, items, reachLimited: p == 3);
                        for (int i = 0; i < res.Length; i++) step[p, i] = 0;
                    }
                    else
                    {
                        // A new step of a few units (now and then 40: a quick turn); the residual is its change.
                        for (int i = 0; i < res.Length; i++)
                        {
                            long next = rng.Next(8) == 0 ? rng.Next(-40, 41) : rng.Next(-2, 3);
                            res[i] = next - step[p, i];
                            step[p, i] = next;
                        }
                        w.Delta(p + 1, 1, res);
                    }
                }
                stream.Add(w.Take());
            }
            return stream;
        }

        // Each record poses its player's avatar, as a game's frame would.
        private sealed class DriveSink : IRecordSink
        {
            public readonly PosecastAvatarDriver[] Drivers = new PosecastAvatarDriver[Players + 1];
            public long Records;

            public void Record(AvatarState a)
            {
                a.Rebuild();
                Drivers[a.AvatarId].Apply(a.Positions, a.World);
                Records++;
            }
        }

        public static void Register()
        {
            var stream = Stream(7);
            var skeleton = SkeletonBlob();

            T.Run("alloc: the test's record writer writes what the reference decoder reads", () =>
            {
                var refs = new Dictionary<long, Recon>();
                for (int p = 1; p <= Players; p++) refs[p] = null;
                int records = 0;
                foreach (var data in stream) records += Records.Decode(data, refs).Count;
                T.Equal(Players * Messages, records, "records");
                var first = Stream(7)[0];
                var got = Records.Decode(first, Fresh());
                T.Equal(1500L * 3, got[3].Recon.RootX, "player 4's root x");
                T.True(got[3].ReachLimited && !got[2].ReachLimited, "flags");
            });

            T.Run("alloc: 16 players x 600 messages decoded in place and driving avatars allocate 0 bytes after warm-up", () =>
            {
                var decoder = new RecordDecoder();
                var sink = new DriveSink();
                for (int p = 1; p <= Players; p++)
                {
                    decoder.Announce(p, skeleton, true);
                    var avatar = UnityEngine.Object.Instantiate(ManagerTests.Prefab(), null);
                    sink.Drivers[p] = avatar.AddComponent<PosecastAvatarDriver>();
                }
                for (int k = 0; k < WarmUp; k++) decoder.Decode(stream[k], 0, stream[k].Length, sink);
                int gc0 = GC.CollectionCount(0);
                long before = GC.GetAllocatedBytesForCurrentThread();
                for (int k = WarmUp; k < Messages; k++) decoder.Decode(stream[k], 0, stream[k].Length, sink);
                long bytes = GC.GetAllocatedBytesForCurrentThread() - before;
                int collections = GC.CollectionCount(0) - gc0;
                Console.WriteLine("    in place: " + (Messages - WarmUp) * Players + " records after warm-up, " + bytes
                                  + " bytes allocated, " + collections + " gen-0 collections");
                T.Equal((long)Players * Messages, sink.Records, "records");
                T.Equal(0L, bytes, "bytes allocated after warm-up");
                var hips = sink.Drivers[2].Avatar.GetBoneTransform(HumanBodyBones.Hips).position;
                T.True(Math.Abs(hips.x + 0.15f) < 0.1f, "player 2's avatar where its root is (x = 0.15 m, Unity -x): " + hips);

                // Control: the immutable API allocates per record, and the counter sees it.
                var refs = new Dictionary<long, Recon>();
                for (int p = 1; p <= Players; p++) refs[p] = null;
                for (int k = 0; k < WarmUp; k++) Records.Decode(stream[k], refs);
                before = GC.GetAllocatedBytesForCurrentThread();
                for (int k = WarmUp; k < Messages; k++) Records.Decode(stream[k], refs);
                long control = GC.GetAllocatedBytesForCurrentThread() - before;
                Console.WriteLine("    control, Records.Decode: " + control / ((Messages - WarmUp) * Players) + " bytes per record");
                T.True(control > 0, "the counter counts");
            });

            T.Run("alloc: the manager's per-frame path (events in, avatars posed through the jitter buffer) allocates nothing", () =>
            {
                var m = new GameObject("posecast").AddComponent<PosecastAvatarManager>();
                m.ConnectOnStart = false;
                m.AvatarPrefab = ManagerTests.Prefab();
                var members = new List<Member> { new Member { Player = "me" } };
                for (int p = 1; p <= Players; p++) members.Add(new Member { Player = "p" + p });
                var onEvent = typeof(PosecastAvatarManager).GetMethod("OnEvent", System.Reflection.BindingFlags.Instance | System.Reflection.BindingFlags.NonPublic);
                onEvent.Invoke(m, new object[] { new ClientEvent { Kind = EventKind.Welcome, Welcome = new Welcome { Player = "me", Members = members.ToArray() } } });
                T.Equal(Players, m.Avatars.Count, "avatars");
                // The session's events, made beforehand (the network thread makes them in a game).
                var session = new ClientSession();
                session.Connected(Protocol.V2);
                var events = new List<ClientEvent>[Messages];
                var welcome = new Welcome
                {
                    Version = Protocol.V2, Player = "me", Session = "s", Role = "player", Room = "lobby", RateHz = 60,
                    Members = new Member[Players], PoseRateHz = 60,
                };
                for (int p = 1; p <= Players; p++) welcome.Members[p - 1] = new Member { Player = "p" + p, Name = "P" + p, AvatarId = p, Skeleton = skeleton };
                session.Receive(Codec.Encode(welcome), 0);
                for (int k = 0; k < Messages; k++)
                    events[k] = session.Receive(Codec.Encode(new Poses { T = 100 + k / 60.0, Data = stream[k] }), 0).Events;
                var pump = (Action<ClientEvent>)Delegate.CreateDelegate(typeof(Action<ClientEvent>), m, onEvent);
                long bytes = 0;
                for (int k = 0; k < Messages; k++)
                {
                    long before = GC.GetAllocatedBytesForCurrentThread();
                    foreach (var e in events[k]) pump(e);
                    m.DriveAvatars(100 + k / 60.0);
                    if (k >= WarmUp) bytes += GC.GetAllocatedBytesForCurrentThread() - before;
                }
                Console.WriteLine("    manager + jitter buffer: " + bytes / (Messages - WarmUp) + " bytes per frame for " + Players + " players");
                T.Equal(0L, bytes, "bytes allocated by the manager's per-frame path after warm-up");
                var hips = m.Avatars["p2"].Avatar.GetBoneTransform(HumanBodyBones.Hips).position;
                T.True(Math.Abs(hips.x + 0.15f) < 0.1f, "p2's avatar where its root is: " + hips);
            });
        }

        private static Dictionary<long, Recon> Fresh()
        {
            var refs = new Dictionary<long, Recon>();
            for (int p = 1; p <= Players; p++) refs[p] = null;
            return refs;
        }
    }
}
