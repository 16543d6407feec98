// Bad server input beyond the vectors: every vector cut short at every length, every
// byte of every valid vector flipped, oversized and wrongly typed messages. A decoder
// answers with a ProtocolException (a code of proto/errors.json) and never anything else.

using System;
using System.IO;

namespace Posecast.Client.Tests
{
    public static class CodecTests
    {
        public static void Register()
        {
            T.Run("codec: every valid vector truncated at every length is MALFORMED or TOO_LARGE", () =>
            {
                int n = 0;
                foreach (var c in ValidCases())
                {
                    var b = T.Hex(c["canonical_hex"].S);
                    for (int len = 0; len < b.Length; len++)
                    {
                        var e = T.Throws<ProtocolException>(() => Codec.Decode(b, 0, len, Protocol.V2), "truncated to " + len);
                        T.True(e.Code == "MALFORMED" || e.Code == "TOO_LARGE", c["name"].S + " cut to " + len + ": " + e.Code);
                        n++;
                    }
                }
                T.True(n > 1000, n + " truncations");
            });
            T.Run("codec: flipping any byte of any vector gives a message or a typed error, never a crash", () =>
            {
                var rng = new Random(20240611);
                int typed = 0;
                foreach (var c in ValidCases())
                {
                    var b = T.Hex(c["canonical_hex"].S);
                    for (int i = 0; i < b.Length; i++)
                    {
                        var m = (byte[])b.Clone();
                        m[i] ^= (byte)(1 + rng.Next(255));
                        foreach (int v in new[] { 1, 2 })
                        {
                            try { Codec.Decode(m, v); }
                            catch (ProtocolException e) { T.True(ErrorCodes.ByCode[e.Code].Decoder, "a decoder code: " + e.Code); typed++; }
                        }
                    }
                }
                T.True(typed > 1000, typed + " typed errors");
            });
            T.Run("codec: v1 refuses over max_message_bytes, v2 over 16384 for server messages", () =>
            {
                var big = Codec.Encode(new Bye { Reason = new string('x', 500) });
                T.Equal("TOO_LARGE", T.Throws<ProtocolException>(() => Codec.Decode(new byte[8193], Protocol.V1), "v1").Code, "v1");
                T.Equal("TOO_LARGE", T.Throws<ProtocolException>(() => Codec.Decode(new byte[16385], Protocol.V2), "v2").Code, "v2");
                var lim = new Limits(new long[] { 1024, 120, 32, 64, 64, 4096, 512, 16 });
                T.Equal("TOO_LARGE", T.Throws<ProtocolException>(() => Codec.Decode(new byte[1025], Protocol.V1, lim), "lowered").Code, "lowered");
                T.True(Codec.Decode(big, Protocol.V1) is Bye, "a bye within the limits decodes");
            });
            T.Run("codec: unknown types and wrong field types get their codes", () =>
            {
                var w = new MsgPackWriter();
                w.Write(MsgValue.NewMap().Add("type", MsgValue.Of("teleport")));
                var e = T.Throws<UnknownTypeException>(() => Codec.Decode(w.ToArray(), Protocol.V2), "unknown");
                T.Equal("type", e.Field, "field");
                w = new MsgPackWriter();
                w.Write(MsgValue.NewMap().Add("type", MsgValue.Of("pong")).Add("t0", MsgValue.Of("1")).Add("t1", MsgValue.Of(1.0)).Add("t2", MsgValue.Of(1.0)));
                T.Equal("t0", T.Throws<BadFieldException>(() => Codec.Decode(w.ToArray(), Protocol.V2), "str t0").Field, "field");
                w = new MsgPackWriter();
                w.Write(MsgValue.NewMap().Add("type", MsgValue.Of("poses")).Add("t", MsgValue.Of(1.0)).Add("data", MsgValue.Of(new byte[] { 0x00, 0x01 })));
                var poses = (Poses)Codec.Decode(w.ToArray(), Protocol.V2);
                var refs = new System.Collections.Generic.Dictionary<long, Recon> { { 0, null } };
                T.Equal("data", T.Throws<BadFieldException>(() => Records.Decode(poses.Data, refs), "keyframe short").Field, "records field");
            });
            T.Run("codec: random record bytes against announced avatar ids: typed errors only", () =>
            {
                var rng = new Random(7);
                int ok = 0, bad = 0;
                for (int k = 0; k < 3000; k++)
                {
                    var data = new byte[rng.Next(1, 300)];
                    rng.NextBytes(data);
                    if (k % 2 == 0) data[0] = (byte)rng.Next(4);
                    var refs = new System.Collections.Generic.Dictionary<long, Recon> { { 0, null }, { 1, null }, { 2, null }, { 3, null } };
                    try { Records.Decode(data, refs); ok++; }
                    catch (BadFieldException e) { T.Equal("data", e.Field, "field"); bad++; }
                }
                T.True(bad > 1000, bad + " refused, " + ok + " decoded");
            });
            T.Run("tracker sets: the server's parsing rule; a set's frames carry its sites", () =>
            {
                var set = TrackerSet.Parse("head,left_hand,right_hand,left_foot:imu,right_foot:imu");
                T.Equal(5, set.Count, "sites");
                T.True(set.Inertial[3] && !set.Inertial[2], "inertial flags");
                T.True(TrackerSet.Of("hmd3") == null, "a named layout is no set");
                foreach (var bad in new[] { "head,left_hand", "head,left_hand,right_hand,tail", "head:imu,left_hand,right_hand", "head,left_hand,right_hand,waist,waist" })
                    T.Throws<ArgumentException>(() => TrackerSet.Parse(bad), bad);
                var session = new ClientSession { Set = set };
                var pos = new Vec3[5];
                var quat = new Quat[5];
                for (int i = 0; i < 5; i++) { pos[i] = new Vec3(0.1 * i, 1.0, 0.0); quat[i] = Quat.Identity; }
                var f = session.BuildFrame(pos, quat, 1.0);
                T.True(f.Sites && f.Valid == 31, "a sites frame, all valid");
                var back = (Frame)Codec.Decode(Codec.Encode(f), Protocol.V2);
                T.True(back.Sites && back.Positions.Length == 5, "round trip");
                T.Equal(0.4, back.Positions[4].X, "row 4");
                T.Throws<ArgumentException>(() => session.BuildFrame(new Vec3[4], new Quat[4], 2.0), "four rows for five sites");
            });
        }

        private static System.Collections.Generic.IEnumerable<Json> ValidCases()
        {
            foreach (var f in Directory.GetFiles(Path.Combine(T.Repo, "proto", "vectors"), "*.json"))
                foreach (var c in Json.Parse(File.ReadAllText(f)).Items)
                    if (c.Has("canonical_hex")) yield return c;
        }
    }
}
