// The Sans-I/O session core: bytes in, events and replies out, no sockets.

using System;
using System.Collections.Generic;
using System.Linq;
using System.Text;

namespace Posecast.Client.Tests
{
    public static class SessionTests
    {
        private static byte[] Enc(Message m) { return Codec.Encode(m); }

        private static Json StreamCase(string name)
        {
            foreach (var c in T.Load("proto", "vectors", "poses.json").Items) if (c["name"].S == name) return c;
            throw new Exception("no vector " + name);
        }

        /// <summary>A v2 session that was welcomed into a room holding the vector's avatars.</summary>
        private static ClientSession Welcomed(Json c)
        {
            var s = new ClientSession();
            s.Connected(Protocol.V2);
            var members = c["avatars"].Items.Select(a => new Member
            {
                Player = a["player"].S, Name = a["player"].S, AvatarId = a["handle"].L, Skeleton = T.Hex(a["skeleton"]["$bin"].S),
            }).ToArray();
            var w = new Welcome
            {
                Version = 2, Player = "me", Session = "s-1", Role = "spectator", Room = "r", T = 10.0, RateHz = 60.0,
                LookaheadFrames = 2, Members = members, PoseRateHz = 60.0,
            };
            var r = s.Receive(Enc(w), 0.0);
            T.True(r.Events.Count == 1 && r.Events[0].Kind == EventKind.Welcome, "welcome event");
            return s;
        }

        public static void Register()
        {
            T.Run("session v2: a welcome's members, then a record stream, give FK poses equal to the vector's", () =>
            {
                var c = StreamCase("poses_stream_two_avatars");
                var s = Welcomed(c);
                int n = 0;
                for (int k = 0; k < c["messages"].Count; k++)
                {
                    var r = s.Receive(T.Hex(c["messages"][k].S), 1.0 + k);
                    var poses = r.Events.Where(e => e.Kind == EventKind.Pose).Select(e => e.Pose).ToList();
                    T.Equal(c["expect"][k].Count, poses.Count, "poses in message " + k);
                    for (int i = 0; i < poses.Count; i++)
                    {
                        var w = c["expect"][k][i];
                        T.Equal(w["handle"].L == 3 ? "p-3" : "p-200", poses[i].Player, "player");
                        T.Equal(w["seq"].L, poses[i].Seq, "seq");
                        T.Equal(w["keyframe"].Bool, poses[i].Keyframe, "keyframe");
                        for (int j = 0; j < 19; j++)
                        {
                            var p = w["positions"][j].Doubles();
                            T.Near(new Vec3(p[0], p[1], p[2]), poses[i].Positions[j], 1e-9, "position " + j);
                            var q = w["items"][j].Doubles();
                            T.NearRot(new Quat(q[0], q[1], q[2], q[3]), poses[i].LocalRotations[j], 1e-9, "local " + j);
                        }
                        n++;
                    }
                    T.True(r.Reply == null && r.End == null, "nothing to answer");
                }
                T.Equal((long)n, s.Stats.Poses, "poses counted");
                T.Equal(0L, s.Stats.BadMessages, "no bad messages");
            });
            T.Run("session v2: a broken record stream drops the references and asks for a resync, at most twice a second", () =>
            {
                var c = StreamCase("poses_stream_two_avatars");
                var s = Welcomed(c);
                s.Receive(T.Hex(c["messages"][0].S), 1.0);
                var delta = T.Hex(c["messages"][1].S);
                var cut = new byte[delta.Length - 3];
                Array.Copy(delta, cut, cut.Length);
                // re-wrap the cut data so the message itself stays valid msgpack
                var msg = (Poses)Codec.Decode(delta, Protocol.V2);
                var broken = Enc(new Poses { T = msg.T, Data = msg.Data.Take(msg.Data.Length - 3).ToArray() });
                var r = s.Receive(broken, 2.0);
                T.True(r.Events.Any(e => e.Kind == EventKind.Bad && ((ProtocolException)e.Cause).Code == "BAD_FIELD"), "a Bad event");
                T.True(r.Reply is Resync, "a resync request");
                r = s.Receive(delta, 2.1); // a delta against a reference the session dropped
                T.True(r.Reply == null && r.Events.Any(e => e.Kind == EventKind.Bad), "no second request within 0.5 s");
                r = s.Receive(delta, 2.6);
                T.True(r.Reply is Resync, "another request after 0.5 s");
                r = s.Receive(T.Hex(c["messages"][0].S), 2.7); // keyframes again
                T.Equal(2, r.Events.Count(e => e.Kind == EventKind.Pose), "keyframes decode");
                T.Equal(2L, s.Stats.Resyncs, "resyncs counted");
            });
            T.Run("session v2: presence join announces, leave forgets; a skeleton message changes the FK", () =>
            {
                var c = StreamCase("poses_stream_two_avatars");
                var s = Welcomed(c);
                var key = T.Hex(c["messages"][0].S);
                T.Equal(2, s.Receive(key, 1.0).Events.Count(e => e.Kind == EventKind.Pose), "both avatars");
                var leave = s.Receive(Enc(new Presence { Event = "leave", Room = "r", Player = "p-200", Name = "p-200" }), 1.1);
                T.True(leave.Events.Single().Kind == EventKind.Presence, "presence event");
                var r = s.Receive(key, 1.2);
                T.True(r.Events.Any(e => e.Kind == EventKind.Bad), "a record for a forgotten avatar id is refused");
                var skel = new byte[108]; // every bone 0: every joint at the pelvis
                s.Receive(Enc(new Presence { Event = "join", Room = "r", Player = "p-200", Name = "x", AvatarId = 200, Skeleton = T.Hex(c["avatars"][1]["skeleton"]["$bin"].S) }), 1.3);
                s.Receive(Enc(new SkeletonMessage { Player = "p-3", AvatarId = 3, Skeleton = skel }), 1.4);
                r = s.Receive(key, 1.5);
                var p3 = r.Events.Where(e => e.Kind == EventKind.Pose && e.Pose.Player == "p-3").Single().Pose;
                T.Near(p3.Positions[0], p3.Positions[(int)Joint.HEAD], 1e-12, "zero bones: the head is at the pelvis");
                // p-3 announced again on another avatar id: its old avatar id is forgotten, as in the other SDKs.
                s.Receive(Enc(new Presence { Event = "join", Room = "r", Player = "p-3", Name = "x", AvatarId = 77, Skeleton = skel }), 1.6);
                T.True(!s.AvatarIds.ContainsKey(3) && s.AvatarIds[77] == "p-3", "one avatar id per player: " + string.Join(",", s.AvatarIds.Keys));
            });
            T.Run("session v1: poses, pong, non-fatal and fatal errors, bye", () =>
            {
                var s = new ClientSession();
                s.Connected(Protocol.V1);
                var pos = new Vec3[19];
                for (int j = 0; j < 19; j++) pos[j] = new Vec3(0.001 * j, 1.0 + 0.01 * j, 0);
                var r = s.Receive(Enc(new Pose { Player = "p-1", Seq = 7, T = 3.0, Positions = pos }), 1.0);
                var p = r.Events.Single().Pose;
                T.True(p.Player == "p-1" && p.Seq == 7 && p.Rotations == null && p.LocalRotations == null, "pose");
                T.Near(pos[5], p.Positions[5], 1e-9, "position");
                s.Receive(Enc(new Pong { T0 = 1.0, T1 = 101.0, T2 = 101.001 }), 1.021);
                T.Near(100.0 - 0.01, s.Clock.OffsetS.Value, 1e-9, "clock offset");
                T.Near(0.02, s.Clock.RttS.Value, 1e-9, "rtt");
                r = s.Receive(Enc(new ErrorMessage { Code = "RATE_LIMITED", Text = "slow down", Fatal = false }), 2.0);
                T.True(r.End == null && r.Events.Single().Kind == EventKind.Error, "non-fatal error is an event");
                r = s.Receive(Enc(new ErrorMessage { Code = "KICKED", Text = "bye", Fatal = true }), 2.0);
                T.True(r.End is KickedException && !((KickedException)r.End).Retryable, "kicked ends, not retryable");
                r = s.Receive(Enc(new Bye { Reason = "SERVER_SHUTDOWN" }), 2.0);
                T.True(r.End is ServerShutdownException && ClientSession.IsRetryable(r.End), "shutdown ends, retryable");
                r = s.Receive(new byte[] { 0xc1 }, 2.0);
                T.True(r.Events.Single().Kind == EventKind.Bad && s.Stats.BadMessages == 1, "garbage is a Bad event, not an exception");
                r = s.Receive(Enc(new Poses { T = 1, Data = new byte[0] }), 2.0);
                T.True(((ProtocolException)r.Events.Single().Cause).Code == "UNKNOWN_TYPE", "poses is not v1");
            });
            T.Run("session: frames count seq on, check trackers, and refuse stale seqs", () =>
            {
                var s = new ClientSession(seq0: 4294967295L);
                var pos = new[] { new Vec3(0, 1.7, 0), new Vec3(0.3, 1, 0), new Vec3(-0.3, 1, 0), new Vec3(double.NaN, 0, 0) };
                var q = new[] { new Quat(0, 0, 0, 2), Quat.Identity, Quat.Identity, new Quat(0, 0, 0, 0) };
                var f = s.BuildFrame(pos, q, 1.0, valid: 0b0111);
                T.Equal(4294967295L, f.Seq, "seq0");
                T.NearRot(Quat.Identity, f.Orientations[0], 1e-15, "normalised");
                T.Near(Vec3.Zero, f.Positions[3], 0, "untracked slot goes as the origin");
                s.Sent(f, 1.0);
                var g = s.BuildFrame(pos, q, 1.1, valid: 0b0111);
                T.Equal(0L, g.Seq, "wraps");
                var decoded = (Frame)Codec.Decode(Codec.Encode(g), Protocol.V2);
                T.True(decoded.Seq == 0 && decoded.Valid == 7, "a frame the server accepts");
                s.Sent(g, 1.1);
                T.Throws<DuplicateException>(() => s.BuildFrame(pos, q, 1.2, valid: 7, seq: 0), "duplicate");
                T.Throws<OutOfOrderException>(() => s.BuildFrame(pos, q, 1.2, valid: 7, seq: 4294967290L), "older");
                T.Equal("trackers[3]", T.Throws<OutOfRangeException>(() => s.BuildFrame(pos, q, 1.2), "NaN tracked").Field, "field");
                var q2 = (Quat[])q.Clone(); q2[3] = Quat.Identity;
                var p2 = (Vec3[])pos.Clone(); p2[3] = new Vec3(0, 1, 0); q2[1] = new Quat(0, 0, 0, 0);
                T.Throws<NotNormalisedException>(() => s.BuildFrame(p2, q2, 1.2), "zero quaternion");
                T.Throws<ArgumentException>(() => s.BuildFrame(pos, q, 0.5, valid: 7), "time going back");
                T.Near(1.1, s.SentAt(0).Value, 0, "sent at");
            });
            T.Run("session: a T-pose calibration checks every row as a tracked frame row and normalises", () =>
            {
                var s = new ClientSession();
                var pos = new[] { new Vec3(0, 1.7, 0), new Vec3(0.8, 1.4, 0), new Vec3(-0.8, 1.4, 0), Vec3.Zero };
                var q = new[] { new Quat(0, 0, 0, 2), Quat.Identity, Quat.Identity, Quat.Identity };
                var c = s.BuildTPose(pos, q);
                T.True(c.TPose && !c.Sites && c.HeightM == null, "a T-pose of the four slots");
                T.NearRot(Quat.Identity, c.Orientations[0], 1e-15, "normalised");
                var decoded = (Calibrate)Codec.Decode(Codec.Encode(c), Protocol.V2);
                T.Near(new Vec3(0.8, 1.4, 0), decoded.Positions[1], 0, "a calibrate the server reads");
                var q2 = (Quat[])q.Clone(); q2[3] = new Quat(0, 0, 0, 0);
                T.Equal("trackers[3]", T.Throws<NotNormalisedException>(() => s.BuildTPose(pos, q2), "every row is read, the waist's too").Field, "field");
                var p2 = (Vec3[])pos.Clone(); p2[2] = new Vec3(0, 2000, 0);
                T.Throws<OutOfRangeException>(() => s.BuildTPose(p2, q), "out of range");
                T.Throws<ArgumentException>(() => s.BuildTPose(new Vec3[3], new Quat[3]), "three rows");
                T.Equal(0L, s.Stats.FramesSent, "no frame counted");
            });
            T.Run("session: hello per version; back-off grows with jitter and stays capped", () =>
            {
                var s = new ClientSession();
                s.Connected(Protocol.V1);
                var h = s.BuildHello("tok", "r", "n", "hmd3+waist", null, null, 30.0);
                T.True(h.Version == 1 && h.Layout == null && h.PoseRateHz == null, "v1 hello");
                s.Connected(Protocol.V2);
                h = s.BuildHello("tok", "r", "n", "hmd3", 90.0, null, 30.0);
                T.True(h.Version == 2 && h.Layout == "hmd3" && h.PoseRateHz == 30.0, "v2 hello");
                T.True(Codec.Decode(Codec.Encode(h), Protocol.V2) is Hello, "the server accepts it");
                h = s.BuildHello("tok", "r", "n", null, null, null, null, 67.0);
                T.True(h.ForecastMs == 67.0 && ((Hello)Codec.Decode(Codec.Encode(h), Protocol.V2)).ForecastMs == 67.0, "v2 forecast");
                T.True(s.BuildHello("tok", "r", "n", null, null, null, null, 0.0).ForecastMs == null, "0: none, left out");
                foreach (var bad in new[] { -1.0, 100.5, double.NaN })
                    T.Throws<ArgumentOutOfRangeException>(() => ClientSession.CheckForecast(bad), "forecast " + bad);
                ClientSession.CheckForecast(100.0);
                s.Connected(Protocol.V1);
                T.True(s.BuildHello("tok", "r", "n", null, null, null, null, 67.0).ForecastMs == null, "v1: no forecast");
                s.Connected(Protocol.V2);
                var rng = new Random(1);
                for (int a = 1; a <= 10; a++)
                {
                    double d = ClientSession.BackoffDelay(a, 0.25, 8.0, rng), cap = Math.Min(8.0, 0.25 * Math.Pow(2, a - 1));
                    T.True(d >= cap / 2 && d <= cap, "attempt " + a + ": " + d);
                }
            });
            T.Run("tokens: a secret shorter than any server takes is refused, counted in characters as the server does", () =>
            {
                string e = "\u00e9", smile = "\ud83d\ude00";  // 2 UTF-8 bytes; one character of two UTF-16 units
                var refused = new Dictionary<string, int>
                {
                    { "", 0 }, { "dev", 3 }, { new string('s', 31), 31 },
                    { string.Concat(Enumerable.Repeat(e, 16)), 16 },  // 32 bytes of UTF-8, 16 characters
                    { smile + new string('s', 30), 31 },  // 32 UTF-16 units, 31 characters
                };
                foreach (var kv in refused)
                {
                    var err = T.Throws<ArgumentException>(() => DevTokens.Mint(kv.Key, "r", "p"), "secret of " + kv.Value);
                    T.True(err.Message.StartsWith("the secret has " + kv.Value + " characters; a server takes none under 32"), err.Message);
                }
                T.Throws<ArgumentException>(() => DevTokens.Mint(null, "r", "p"), "no secret");
                foreach (var ok in new[] { new string('s', 32), string.Concat(Enumerable.Repeat(e, 32)), smile + new string('s', 31) })
                    T.Equal(3, DevTokens.Mint(ok, "r", "p").Split('.').Length, "a token from a secret of 32 characters");
            });
            T.Run("tokens: ttlS and the room and player are checked as mint_token checks them", () =>
            {
                string secret = new string('s', 32), id64 = new string('a', 64);
                foreach (int ttl in new[] { 0, -1, DevTokens.MaxTtlS + 1, int.MinValue })
                {
                    var err = T.Throws<ArgumentException>(() => DevTokens.Mint(secret, "r", "p", ttlS: ttl), "ttlS " + ttl);
                    T.Equal("ttlS must be in (0, 604800], not " + ttl, err.Message, "ttlS " + ttl);
                }
                foreach (int ttl in new[] { 1, DevTokens.MaxTtlS })
                    T.Equal(3, DevTokens.Mint(secret, "r", "p", ttlS: ttl).Split('.').Length, "ttlS " + ttl);
                foreach (var bad in new[] { "", "lob by", "a/b", "caf\u00e9", "\u0661", id64 + "a", "r\n" })
                {
                    var err = T.Throws<ArgumentException>(() => DevTokens.Mint(secret, bad, "p"), "room " + bad);
                    T.Equal("room '" + bad + "' is not an id: 1 to 64 of A-Z a-z 0-9 _ . : -", err.Message, "room " + bad);
                    err = T.Throws<ArgumentException>(() => DevTokens.Mint(secret, "r", bad), "player " + bad);
                    T.True(err.Message.StartsWith("player '" + bad + "' is not an id"), err.Message);
                }
                T.Equal("no room (null)", T.Throws<ArgumentException>(() => DevTokens.Mint(secret, null, "p"), "null room").Message, "null room");
                T.Equal("no player (null)", T.Throws<ArgumentException>(() => DevTokens.Mint(secret, "r", null), "null player").Message, "null player");
                T.Equal(3, DevTokens.Mint(secret, id64, "Ab_0.9:-z").Split('.').Length, "64 bytes and every id character");
            });
            T.Run("tokens: HS256 JWTs, byte for byte what the Python SDK's mint_token writes", () =>
            {
                // client_sdk/python/tests/test_tokens.py's GOLDEN_PLAYER: the same secret and arguments.
                string golden = "eyJhbGciOiJIUzI1NiIsInR5cCI6IkpXVCJ9.eyJyb29tIjoibG9iYnkiLCJwbGF5ZXIiOiJhZGEiLCJyb2xlIjoicGxh"
                                + "eWVyIiwiaWF0IjoxNzAwMDAwMDAwLCJleHAiOjE3MDAwMDA2MDAsImp0aSI6ImotMSJ9."
                                + "TyecKK-bRxsHDcw7o2ZWdiGswDDliclFuP6O43sBC7I";
                T.Equal(golden, DevTokens.MintAt("dev-secret-0123456789-abcdefghijk", "lobby", "ada", "player", 600, null,
                                                 1700000000, "j-1"), "golden token");
                string withKid = DevTokens.MintAt(new string('s', 32), "r", "p", "player", 60, "2026-12", 1700000000, "j");
                string part = withKid.Split('.')[0].Replace('-', '+').Replace('_', '/');
                string header = Encoding.UTF8.GetString(Convert.FromBase64String(part + new string('=', (4 - part.Length % 4) % 4)));
                T.Equal("{\"alg\":\"HS256\",\"kid\":\"2026-12\",\"typ\":\"JWT\"}", header, "header with a kid");
            });
        }
    }
}
