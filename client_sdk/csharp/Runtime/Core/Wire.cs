// Per message type: the wire map -> message check, and the message -> canonical map.
//
// v2 (posecast.v2) keeps every v1 type but pose, adds poses, skeleton, pose_rate,
// resync and forecast, and changes hello (version 2, pose_rate_hz, forecast_ms),
// welcome (members with handle and skeleton, pose_rate_hz, forecast_ms) and presence
// (a join carries handle and skeleton). The wire's "handle" is the avatar id (AvatarId
// in the messages). A decoder reads every known field with the Fields validators and
// ignores the rest; an encoder builds the map in canonical key order (type, then the
// spec's field order), leaving absent optionals out and writing every float field as
// float64.

using System;
using System.Collections.Generic;

namespace Posecast.Client
{
    internal static class Wire
    {
        private const double TMax = Protocol.MaxTimeS;

        // --- decoders ---------------------------------------------------------------

        public static Message Decode(string type, MsgValue m, Limits lim, int v)
        {
            switch (type)
            {
                case "hello": return DecHello(m, lim, v);
                case "welcome": return DecWelcome(m, lim, v);
                case "calibrate": return DecCalibrate(m);
                case "frame": return DecFrame(m);
                case "pose": return DecPose(m);
                case "presence": return DecPresence(m, lim, v);
                case "selector": return DecSelector(m);
                case "kick": return new Kick { Player = Fields.Id(m, "player", Protocol.MaxIdBytes), Reason = Text(m, "reason", lim) };
                case "ping": return new Ping { T0 = Fields.Float(m, "t0", 0.0, TMax) };
                case "pong":
                    return new Pong { T0 = Fields.Float(m, "t0", 0.0, TMax), T1 = Fields.Float(m, "t1", 0.0, TMax),
                                      T2 = Fields.Float(m, "t2", 0.0, TMax) };
                case "error": return DecError(m, lim);
                case "bye": return new Bye { Reason = Text(m, "reason", lim) };
                case "poses": return new Poses { T = Fields.Float(m, "t", 0.0, TMax), Data = Data(m) };
                case "skeleton":
                    return new SkeletonMessage { Player = Fields.Id(m, "player", Protocol.MaxIdBytes),
                                                 AvatarId = AvatarId(m, "handle"), Skeleton = SkeletonBin(m, "skeleton") };
                case "pose_rate": return new PoseRate { RateHz = PoseRateHz(m, "rate_hz") };
                case "resync": return new Resync();
                case "forecast": return new Forecast { Ms = ForecastMs(m, "ms") };
                default: throw new InvalidOperationException(type);
            }
        }

        private static string Text(MsgValue m, string key, Limits lim)
        {
            return Fields.Has(m, key) ? Fields.Str(m, key, lim.MaxTextBytes, 0) : null;
        }

        private static double ForecastMs(MsgValue m, string key)
        {
            return Fields.Float(m, key, 0.0, Protocol.MaxForecastMs);
        }

        private static double PoseRateHz(MsgValue m, string key)
        {
            double v = Fields.Float(m, key, 0.0, 1000.0);
            if (Array.IndexOf(Protocol.PoseRatesHz, v) < 0)
                throw ErrorCodes.OutOfRange(key, key + "=" + v + " is not one of 60, 30, 20, 15");
            return v;
        }

        /// <summary>An avatar id, read from its wire key (`key` is "handle").</summary>
        private static long AvatarId(MsgValue m, string key, string at = "")
        {
            return Fields.Int(m, key, 0, Protocol.UInt32Max, at);
        }

        private static byte[] SkeletonBin(MsgValue m, string key, string at = "")
        {
            return Fields.Bin(m, key, Records.SkeletonBytes, at);
        }

        private static byte[] Data(MsgValue m)
        {
            var v = m.Get("data");
            if (v == null || v.Kind != MsgKind.Bin) throw ErrorCodes.BadField("data", "data: expected a bin");
            return v.Bin;
        }

        private static Hello DecHello(MsgValue m, Limits lim, int v)
        {
            var version = m.Get("version");
            if (version == null || version.Kind != MsgKind.Int)
                throw ErrorCodes.BadField("version", "field version must be an integer");
            if (version.IsHugeUInt || version.Int != v)
                throw new VersionUnsupportedException("version " + version + " is not supported on posecast.v" + v).At("version");
            var h = new Hello { Version = version.Int };
            if (v >= Protocol.V2 && Fields.Has(m, "pose_rate_hz")) h.PoseRateHz = PoseRateHz(m, "pose_rate_hz");
            if (v >= Protocol.V2 && Fields.Has(m, "forecast_ms")) h.ForecastMs = ForecastMs(m, "forecast_ms");
            h.Token = Fields.Str(m, "token", lim.MaxTokenBytes, 0);
            h.Room = Fields.Id(m, "room", lim.MaxRoomBytes);
            h.Name = Fields.Name(m, "name", lim.MaxNameBytes);
            if (Fields.Has(m, "layout")) h.Layout = Layout(m);
            if (Fields.Has(m, "rate_hz")) h.RateHz = Fields.Float(m, "rate_hz", 1.0, lim.MaxRateHz);
            if (Fields.Has(m, "watch"))
            {
                var items = Fields.List(m, "watch", lim.MaxWatchRooms);
                var watch = new string[items.Count];
                for (int i = 0; i < items.Count; i++)
                {
                    string k = "watch[" + i + "]";
                    watch[i] = Fields.Id(MsgValue.NewMap().Add(k, items[i]), k, lim.MaxRoomBytes);
                }
                h.Watch = watch;
            }
            return h;
        }

        private static Welcome DecWelcome(MsgValue m, Limits lim, int v)
        {
            var items = Fields.List(m, "members", lim.MaxPlayers);
            var members = new Member[items.Count];
            for (int i = 0; i < items.Count; i++)
            {
                string at = "members[" + i + "].";
                var item = items[i];
                if (item.Kind != MsgKind.Map) throw ErrorCodes.BadField("members[" + i + "]", "members[" + i + "]: expected a map");
                var mem = new Member
                {
                    Player = Fields.Id(item, "player", Protocol.MaxIdBytes, at),
                    Name = Fields.Name(item, "name", lim.MaxNameBytes, at),
                };
                if (v >= Protocol.V2)
                {
                    mem.AvatarId = AvatarId(item, "handle", at);
                    mem.Skeleton = SkeletonBin(item, "skeleton", at);
                }
                members[i] = mem;
            }
            var lm = Fields.Map(m, "limits");
            var values = new long[Limits.Names.Length];
            for (int k = 0; k < values.Length; k++)
                values[k] = Fields.Int(lm, Limits.Names[k], Limits.Floor[k], Limits.Max[k], "limits.");
            var w = new Welcome
            {
                Version = Fields.Int(m, "version", 1, 255),
                Player = Fields.Id(m, "player", Protocol.MaxIdBytes),
                Session = Fields.Id(m, "session", Protocol.MaxIdBytes),
                Role = Fields.Enum(m, "role", Protocol.Roles),
                Room = Fields.Id(m, "room", lim.MaxRoomBytes),
                T = Fields.Float(m, "t", 0.0, TMax),
                RateHz = Fields.Float(m, "rate_hz", 1.0, 1000.0),
                LookaheadFrames = Fields.Int(m, "lookahead_frames", 0, Protocol.MaxLookaheadFrames),
                Members = members,
                Limits = new Limits(values),
            };
            if (v >= Protocol.V2) w.PoseRateHz = PoseRateHz(m, "pose_rate_hz");
            if (v >= Protocol.V2 && Fields.Has(m, "forecast_ms")) w.ForecastMs = ForecastMs(m, "forecast_ms");
            return w;
        }

        private static Calibrate DecCalibrate(MsgValue m)
        {
            bool hasHeight = Fields.Has(m, "height_m"), hasTpose = Fields.Has(m, "tpose");
            if (hasTpose && !Fields.Bool(m, "tpose")) throw ErrorCodes.BadField("tpose", "tpose, when present, must be true");
            if (hasHeight && hasTpose) throw ErrorCodes.BadField("tpose", "give height_m or tpose, not both");
            if (hasHeight) return new Calibrate { HeightM = Fields.Float(m, "height_m", Protocol.MinHeightM, Protocol.MaxHeightM) };
            if (!hasTpose) throw ErrorCodes.BadField("height_m", "calibrate needs height_m or tpose: true");
            Vec3[] pos; Quat[] quat;
            if (Fields.Has(m, "sites"))
            {
                if (Fields.Has(m, "trackers")) throw ErrorCodes.BadField("sites", "give trackers or sites, not both");
                Fields.Sites(m, "sites", null, out pos, out quat);
                return new Calibrate { Positions = pos, Orientations = quat, Sites = true };
            }
            Fields.Trackers(m, "trackers", Protocol.AllTrackersValid, out pos, out quat);
            return new Calibrate { Positions = pos, Orientations = quat };
        }

        /// <summary>hello.layout: a named layout or a tracker set (BAD_FIELD saying why not).</summary>
        private static string Layout(MsgValue m)
        {
            string text = Fields.Str(m, "layout", TrackerSet.MaxLayoutBytes);
            if (Array.IndexOf(Protocol.Layouts, text) >= 0) return text;
            try { TrackerSet.Parse(text); }
            catch (ArgumentException exc)
            {
                throw ErrorCodes.BadField("layout", "layout '" + text + "': " + exc.Message
                    + " (a named layout: " + string.Join(", ", Protocol.Layouts) + ", or a tracker set)");
            }
            return text;
        }

        private static Frame DecFrame(MsgValue m)
        {
            long seq = Fields.Int(m, "seq", 0, Protocol.UInt32Max);
            try
            {
                double t = Fields.Float(m, "t", 0.0, TMax);
                if (Fields.Has(m, "sites"))
                {
                    if (Fields.Has(m, "trackers")) throw ErrorCodes.BadField("sites", "give trackers or sites, not both");
                    int? mask = Fields.Has(m, "valid") ? (int?)Fields.Int(m, "valid", 0, (1 << TrackerSet.MaxSites) - 1) : null;
                    Vec3[] sp; Quat[] sq;
                    int sv = Fields.Sites(m, "sites", mask, out sp, out sq);
                    return new Frame { Seq = seq, T = t, Positions = sp, Orientations = sq, Valid = sv, Sites = true };
                }
                int valid = Fields.Has(m, "valid") ? (int)Fields.Int(m, "valid", 0, Protocol.AllTrackersValid) : Protocol.AllTrackersValid;
                Vec3[] pos; Quat[] quat;
                Fields.Trackers(m, "trackers", valid, out pos, out quat);
                return new Frame { Seq = seq, T = t, Positions = pos, Orientations = quat, Valid = valid };
            }
            catch (ProtocolException exc)
            {
                exc.RefSeq = seq;
                throw;
            }
        }

        private static Pose DecPose(MsgValue m)
        {
            var root = Fields.Point(m, "root");
            byte[] rot = Fields.Has(m, "rot") ? Fields.Bin(m, "rot", Quantize.RotBytes) : null;
            var p = new Pose
            {
                Player = Fields.Id(m, "player", Protocol.MaxIdBytes),
                Seq = Fields.Int(m, "seq", 0, Protocol.UInt32Max),
                T = Fields.Float(m, "t", 0.0, TMax),
            };
            p.Positions = Quantize.Mm2Pos(root, Fields.Bin(m, "pos_mm", Quantize.PosBytes));
            p.Rotations = rot == null ? null : Quantize.Snorm2Quat(rot);
            return p;
        }

        private static Presence DecPresence(MsgValue m, Limits lim, int v)
        {
            var p = new Presence { Event = Fields.Enum(m, "event", Protocol.PresenceEvents) };
            p.Room = Fields.Id(m, "room", lim.MaxRoomBytes);
            p.Player = Fields.Id(m, "player", Protocol.MaxIdBytes);
            p.Name = Fields.Name(m, "name", lim.MaxNameBytes);
            if (v >= Protocol.V2 && p.Event == "join")
            {
                p.AvatarId = AvatarId(m, "handle");
                p.Skeleton = SkeletonBin(m, "skeleton");
            }
            return p;
        }

        private static readonly string[] SelectorKeys = { "joint", "point", "radius_m", "margin_m", "factor" };

        private static bool Applies(string kind, string key)
        {
            switch (kind)
            {
                case "anomaly": return key == "factor";
                case "target": return key == "joint" || key == "point" || key == "margin_m";
                default: return key == "joint" || key == "point" || key == "radius_m";
            }
        }

        private static Selector DecSelector(MsgValue m)
        {
            var s = new Selector { Player = Fields.Id(m, "player", Protocol.MaxIdBytes) };
            s.Kind = Fields.Enum(m, "kind", Protocol.SelectorKinds);
            foreach (var key in SelectorKeys)
                if (Fields.Has(m, key) && !Applies(s.Kind, key))
                    throw ErrorCodes.BadField(key, key + " does not apply to a " + s.Kind + " selector");
            if (s.Kind != "anomaly")
            {
                s.Joint = Fields.Enum(m, "joint", Protocol.JointNames);
                s.Point = Fields.Point(m, "point");
            }
            if (Fields.Has(m, "radius_m")) s.RadiusM = Fields.Float(m, "radius_m", 0.001, 10.0);
            if (Fields.Has(m, "margin_m")) s.MarginM = Fields.Float(m, "margin_m", 0.0, 10.0);
            if (Fields.Has(m, "factor")) s.Factor = Fields.Float(m, "factor", 0.1, 100.0);
            return s;
        }

        public static bool IsCode(string code)
        {
            if (code.Length < 1 || code.Length > 32 || code[0] < 'A' || code[0] > 'Z') return false;
            foreach (char c in code)
                if (!((c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '_')) return false;
            return true;
        }

        private static ErrorMessage DecError(MsgValue m, Limits lim)
        {
            string code = Fields.Str(m, "code", 32);
            if (!IsCode(code)) throw ErrorCodes.BadField("code", "code must be upper-case letters, digits and _");
            return new ErrorMessage
            {
                Code = code,
                Text = Fields.Str(m, "message", lim.MaxTextBytes, 0),
                Fatal = Fields.Bool(m, "fatal"),
                Field = Text(m, "field", lim),
                RefSeq = Fields.Has(m, "ref_seq") ? Fields.Int(m, "ref_seq", 0, Protocol.UInt32Max) : (long?)null,
            };
        }

        // --- encoders -----------------------------------------------------------------

        private static MsgValue F(double v) { return MsgValue.Of(v); }
        private static MsgValue I(long v) { return MsgValue.Of(v); }
        private static MsgValue S(string v) { return MsgValue.Of(v); }

        private static MsgValue Head(string type) { return MsgValue.NewMap().Add("type", S(type)); }

        private static MsgValue Trackers(Vec3[] pos, Quat[] quat)
        {
            var rows = new List<MsgValue>(pos.Length);
            for (int i = 0; i < pos.Length; i++)
                rows.Add(MsgValue.Array(F(pos[i].X), F(pos[i].Y), F(pos[i].Z),
                                        F(quat[i].X), F(quat[i].Y), F(quat[i].Z), F(quat[i].W)));
            return MsgValue.Array(rows);
        }

        /// <summary>The canonical wire map of a message (keys in canonical order).</summary>
        public static MsgValue ToWire(Message msg)
        {
            switch (msg.Type)
            {
                case "hello":
                {
                    var h = (Hello)msg;
                    var d = Head("hello").Add("version", I(h.Version)).Add("token", S(h.Token)).Add("room", S(h.Room)).Add("name", S(h.Name));
                    if (h.Layout != null) d.Add("layout", S(h.Layout));
                    if (h.RateHz.HasValue) d.Add("rate_hz", F(h.RateHz.Value));
                    if (h.Watch != null && h.Watch.Length > 0)
                    {
                        var w = new List<MsgValue>();
                        foreach (var r in h.Watch) w.Add(S(r));
                        d.Add("watch", MsgValue.Array(w));
                    }
                    if (h.PoseRateHz.HasValue) d.Add("pose_rate_hz", F(h.PoseRateHz.Value));
                    if (h.ForecastMs.HasValue) d.Add("forecast_ms", F(h.ForecastMs.Value));
                    return d;
                }
                case "welcome":
                {
                    var w = (Welcome)msg;
                    var members = new List<MsgValue>();
                    foreach (var p in w.Members)
                    {
                        var mm = MsgValue.NewMap().Add("player", S(p.Player)).Add("name", S(p.Name));
                        if (p.AvatarId.HasValue) mm.Add("handle", I(p.AvatarId.Value)); // the avatar id's wire key
                        if (p.Skeleton != null) mm.Add("skeleton", MsgValue.Of(p.Skeleton));
                        members.Add(mm);
                    }
                    var limits = MsgValue.NewMap();
                    for (int k = 0; k < Limits.Names.Length; k++) limits.Add(Limits.Names[k], I(w.Limits.Values[k]));
                    var d = Head("welcome").Add("version", I(w.Version)).Add("player", S(w.Player)).Add("session", S(w.Session))
                        .Add("role", S(w.Role)).Add("room", S(w.Room)).Add("t", F(w.T)).Add("rate_hz", F(w.RateHz))
                        .Add("lookahead_frames", I(w.LookaheadFrames)).Add("members", MsgValue.Array(members)).Add("limits", limits);
                    if (w.PoseRateHz.HasValue) d.Add("pose_rate_hz", F(w.PoseRateHz.Value));
                    if (w.ForecastMs.HasValue) d.Add("forecast_ms", F(w.ForecastMs.Value));
                    return d;
                }
                case "calibrate":
                {
                    var c = (Calibrate)msg;
                    if (!c.TPose) return Head("calibrate").Add("height_m", F(c.HeightM.Value));
                    return Head("calibrate").Add("tpose", MsgValue.True).Add(c.Sites ? "sites" : "trackers", Trackers(c.Positions, c.Orientations));
                }
                case "frame":
                {
                    var f = (Frame)msg;
                    var d = Head("frame").Add("seq", I(f.Seq)).Add("t", F(f.T)).Add(f.Sites ? "sites" : "trackers", Trackers(f.Positions, f.Orientations));
                    if (f.Valid != (1 << f.Positions.Length) - 1) d.Add("valid", I(f.Valid));
                    return d;
                }
                case "pose":
                {
                    var p = (Pose)msg;
                    var root = p.Positions[0];
                    var d = Head("pose").Add("player", S(p.Player)).Add("seq", I(p.Seq)).Add("t", F(p.T))
                        .Add("root", MsgValue.Array(F(root.X), F(root.Y), F(root.Z)))
                        .Add("pos_mm", MsgValue.Of(Quantize.Pos2Mm(p.Positions)));
                    if (p.Rotations != null) d.Add("rot", MsgValue.Of(Quantize.Quat2Snorm(p.Rotations)));
                    return d;
                }
                case "presence":
                {
                    var p = (Presence)msg;
                    var d = Head("presence").Add("event", S(p.Event)).Add("room", S(p.Room)).Add("player", S(p.Player)).Add("name", S(p.Name));
                    if (p.AvatarId.HasValue) d.Add("handle", I(p.AvatarId.Value)); // the avatar id's wire key
                    if (p.Skeleton != null) d.Add("skeleton", MsgValue.Of(p.Skeleton));
                    return d;
                }
                case "poses":
                {
                    var p = (Poses)msg;
                    return Head("poses").Add("t", F(p.T)).Add("data", MsgValue.Of(p.Data));
                }
                case "skeleton":
                {
                    var k = (SkeletonMessage)msg;
                    // "handle": the avatar id's wire key
                    return Head("skeleton").Add("player", S(k.Player)).Add("handle", I(k.AvatarId)).Add("skeleton", MsgValue.Of(k.Skeleton));
                }
                case "pose_rate": return Head("pose_rate").Add("rate_hz", F(((PoseRate)msg).RateHz));
                case "resync": return Head("resync");
                case "forecast": return Head("forecast").Add("ms", F(((Forecast)msg).Ms));
                case "selector":
                {
                    var s = (Selector)msg;
                    var d = Head("selector").Add("player", S(s.Player)).Add("kind", S(s.Kind));
                    if (s.Joint != null) d.Add("joint", S(s.Joint));
                    if (s.Point.HasValue) d.Add("point", MsgValue.Array(F(s.Point.Value.X), F(s.Point.Value.Y), F(s.Point.Value.Z)));
                    if (s.RadiusM.HasValue) d.Add("radius_m", F(s.RadiusM.Value));
                    if (s.MarginM.HasValue) d.Add("margin_m", F(s.MarginM.Value));
                    if (s.Factor.HasValue) d.Add("factor", F(s.Factor.Value));
                    return d;
                }
                case "kick":
                {
                    var k = (Kick)msg;
                    var d = Head("kick").Add("player", S(k.Player));
                    if (k.Reason != null) d.Add("reason", S(k.Reason));
                    return d;
                }
                case "ping": return Head("ping").Add("t0", F(((Ping)msg).T0));
                case "pong":
                {
                    var p = (Pong)msg;
                    return Head("pong").Add("t0", F(p.T0)).Add("t1", F(p.T1)).Add("t2", F(p.T2));
                }
                case "error":
                {
                    var e = (ErrorMessage)msg;
                    var d = Head("error").Add("code", S(e.Code)).Add("message", S(e.Text)).Add("fatal", MsgValue.Of(e.Fatal));
                    if (e.Field != null) d.Add("field", S(e.Field));
                    if (e.RefSeq.HasValue) d.Add("ref_seq", I(e.RefSeq.Value));
                    return d;
                }
                case "bye":
                {
                    var b = (Bye)msg;
                    var d = Head("bye");
                    if (b.Reason != null) d.Add("reason", S(b.Reason));
                    return d;
                }
                default: throw new ArgumentException("not a posecast message: " + msg.Type);
            }
        }
    }
}
