// proto/vectors/*.json, every case in every protocol version it lists:
//   valid:   decode(canonical) re-encodes to it byte for byte, its wire map equals
//            `message`, and every also_accept_hex decodes and re-encodes to canonical;
//   invalid: decoding fails with exactly `error`, and `field` where one is given;
//   stream:  the poses messages decode, record by record, to `expect` (or the last
//            one fails with `error`).

using System;
using System.Collections.Generic;
using System.IO;

namespace Posecast.Client.Tests
{
    public static class VectorTests
    {
        public static int Cases;

        public static void Register()
        {
            var dir = Path.Combine(T.Repo, "proto", "vectors");
            var files = Directory.GetFiles(dir, "*.json");
            Array.Sort(files, StringComparer.Ordinal);
            T.Run("vectors: one file per message type of v1 and v2, plus envelope", () =>
            {
                var want = new SortedSet<string>(Protocol.TypesV1);
                want.UnionWith(Protocol.TypesV2);
                want.Add("envelope");
                var got = new SortedSet<string>(Array.ConvertAll(files, f => Path.GetFileNameWithoutExtension(f)));
                T.Equal(string.Join(" ", want), string.Join(" ", got), "files");
            });
            foreach (var file in files)
            {
                var stem = Path.GetFileNameWithoutExtension(file);
                var cases = Json.Parse(File.ReadAllText(file));
                foreach (var c in cases.Items)
                {
                    Cases++;
                    string name = stem + "/" + c["name"].S;
                    if (c.Has("messages")) { T.Run(name, () => Stream(c)); continue; }
                    foreach (var v in c["versions"].Items)
                    {
                        int version = (int)v.L;
                        if (c.Has("message")) T.Run("v" + version + " " + name, () => Valid(c, version));
                        else T.Run("v" + version + " " + name, () => Invalid(c, version));
                    }
                }
            }
        }

        /// <summary>A JSON message as its wire value: {"$bin": hex} is a bin, 1.0 a float, 1 an int.</summary>
        public static MsgValue FromJson(Json j)
        {
            switch (j.Kind)
            {
                case JsonKind.Null: return MsgValue.Nil;
                case JsonKind.Bool: return MsgValue.Of(j.Bool);
                case JsonKind.String: return MsgValue.Of(j.S);
                case JsonKind.Number:
                    if (j.IsFloatText) return MsgValue.Of(j.D);
                    if (j.Text.StartsWith("-")) return MsgValue.Of(j.L);
                    ulong u = ulong.Parse(j.Text);
                    return u > long.MaxValue ? MsgValue.HugeUInt(u) : MsgValue.Of((long)u);
                case JsonKind.Array:
                {
                    var items = new List<MsgValue>();
                    foreach (var x in j.Items) items.Add(FromJson(x));
                    return MsgValue.Array(items);
                }
                default:
                    if (j.Fields.Count == 1 && j.Fields[0].Key == "$bin") return MsgValue.Of(T.Hex(j.Fields[0].Value.S));
                    var m = MsgValue.NewMap();
                    foreach (var f in j.Fields) m.Add(f.Key, FromJson(f.Value));
                    return m;
            }
        }

        private static void Valid(Json c, int version)
        {
            var canonical = T.Hex(c["canonical_hex"].S);
            var msg = Codec.Decode(canonical, version);
            T.Equal(c["canonical_hex"].S, T.ToHex(Codec.Encode(msg)), "re-encoded");
            var want = FromJson(c["message"]);
            var got = Codec.ToWire(msg);
            T.True(got.SameAs(want), "wire map: want " + want + "\n   got " + got);
            foreach (var alt in c["also_accept_hex"].Items)
            {
                Message m;
                try { m = Codec.Decode(T.Hex(alt.S), version); }
                catch (ProtocolException e) { throw new AssertException("also_accept " + alt.S.Substring(0, Math.Min(40, alt.S.Length)) + "...: " + e); }
                T.Equal(c["canonical_hex"].S, T.ToHex(Codec.Encode(m)), "also_accept re-encoded");
            }
        }

        private static void Invalid(Json c, int version)
        {
            var e = T.Throws<ProtocolException>(() => Codec.Decode(T.Hex(c["hex"].S), version), "decode");
            T.Equal(c["error"].S, e.Code, "code (" + e.Message + ")");
            T.Equal(c.Has("field") ? c["field"].S : null, e.Field, "field");
        }

        private sealed class Snapshots : IRecordSink
        {
            public readonly List<Tuple<long, long, bool, bool, Vec3, Quat[], Vec3[]>> Taken = new List<Tuple<long, long, bool, bool, Vec3, Quat[], Vec3[]>>();

            public void Record(AvatarState a)
            {
                a.Rebuild();
                Taken.Add(Tuple.Create(a.AvatarId, a.Seq, a.Keyframe, a.ReachLimited, a.Root, (Quat[])a.Items.Clone(), (Vec3[])a.Positions.Clone()));
            }
        }

        private static void Stream(Json c)
        {
            var refs = new Dictionary<long, Recon>();
            var bones = new Dictionary<long, Vec3[]>();
            var inPlace = new RecordDecoder(); // the allocation-free decoder, alongside
            var seen = new Snapshots();
            foreach (var a in c["avatars"].Items)
            {
                refs[a["handle"].L] = null;
                bones[a["handle"].L] = Records.BytesToSkeleton(T.Hex(a["skeleton"]["$bin"].S));
                inPlace.Announce(a["handle"].L, T.Hex(a["skeleton"]["$bin"].S), true);
            }
            double tol = c["tolerance"].D;
            var messages = c["messages"].Items;
            for (int k = 0; k < messages.Count; k++)
            {
                var msg = Codec.Decode(T.Hex(messages[k].S), Protocol.V2) as Poses;
                T.True(msg != null, "message " + k + " is a poses");
                if (c.Has("error") && k == messages.Count - 1)
                {
                    var e = T.Throws<ProtocolException>(() => Records.Decode(msg.Data, refs), "records");
                    T.Equal(c["error"].S, e.Code, "code");
                    T.Equal(c["field"].S, e.Field, "field");
                    var e2 = T.Throws<ProtocolException>(() => inPlace.Decode(msg.Data, 0, msg.Data.Length, null), "records in place");
                    T.Equal(e.Code + " " + e.Field + " " + e.Message, e2.Code + " " + e2.Field + " " + e2.Message, "the same error in place");
                    return;
                }
                var got = Records.Decode(msg.Data, refs);
                var want = c["expect"][k];
                T.Equal(want.Count, got.Count, "records in message " + k);
                seen.Taken.Clear();
                T.Equal(got.Count, inPlace.Decode(msg.Data, 0, msg.Data.Length, seen), "records in place in message " + k);
                for (int i = 0; i < got.Count; i++)
                {
                    var w = want[i];
                    var r = got[i];
                    string at = "message " + k + " record " + i;
                    T.Equal(w["handle"].L, r.AvatarId, at + " avatar id");
                    T.Equal(w["seq"].L, r.Recon.Seq, at + " seq");
                    T.Equal(w["keyframe"].Bool, r.Keyframe, at + " keyframe");
                    T.Equal(w["reach_limited"].Bool, r.ReachLimited, at + " reach_limited");
                    var root = w["root"].Doubles();
                    T.Near(new Vec3(root[0], root[1], root[2]), r.Recon.Root, tol, at + " root");
                    for (int j = 0; j < Protocol.NumJoints; j++)
                    {
                        var q = w["items"][j].Doubles();
                        var gq = r.Recon.Items[j];
                        T.Near(q[0], gq.X, tol, at + " item " + j + ".x"); T.Near(q[1], gq.Y, tol, at + " item " + j + ".y");
                        T.Near(q[2], gq.Z, tol, at + " item " + j + ".z"); T.Near(q[3], gq.W, tol, at + " item " + j + ".w");
                    }
                    var pos = Records.Positions(r.Recon.Root, Records.ItemsToWorld(r.Recon.Items), bones[r.AvatarId]);
                    for (int j = 0; j < Protocol.NumJoints; j++)
                    {
                        var p = w["positions"][j].Doubles();
                        T.Near(new Vec3(p[0], p[1], p[2]), pos[j], tol, at + " position " + j);
                    }
                    // In place: the very same numbers (one code path), FK into the state's arrays.
                    var s = seen.Taken[i];
                    T.Equal(r.AvatarId + " " + r.Recon.Seq + " " + r.Keyframe + " " + r.ReachLimited + " " + r.Recon.Root,
                            s.Item1 + " " + s.Item2 + " " + s.Item3 + " " + s.Item4 + " " + s.Item5, at + " in place");
                    for (int j = 0; j < Protocol.NumJoints; j++)
                    {
                        T.Equal(r.Recon.Items[j], s.Item6[j], at + " in place item " + j);
                        T.Equal(pos[j], s.Item7[j], at + " in place position " + j);
                    }
                }
            }
            T.True(!c.Has("error"), "the error case failed before its last message");
        }
    }
}
