// The client's protocol state (Sans-I/O): bytes in, events and replies out.
//
// One ClientSession lives as long as the PosecastClient, across reconnects. It builds
// hello and checked frame messages, keeps seq increasing (never restarting on a new
// connection, so a pose's seq always names one frame this client sent), feeds pong
// into the clock, and turns what the server sends into events: on posecast.v1 each
// pose message is one PlayerPose; on posecast.v2 it keeps every announced avatar's
// avatar id, skeleton and reference, decodes each poses message's records and rebuilds
// joint positions by FK. No sockets, no clocks: the caller passes `now`.
//
// Bad server input never throws out of Receive: a message the codec refuses is
// counted (Stats.BadMessages) and reported as a Bad event; a v2 record stream that
// no longer decodes drops every reference and asks the server for keyframes (resync,
// at most one request per ResyncEveryS).

using System;
using System.Collections.Generic;

namespace Posecast.Client
{
    /// <summary>One avatar's pose as received: world positions and rotations, joint order.</summary>
    public sealed class PlayerPose : IPose
    {
        public string Player { get; set; }
        public long Seq { get; set; }
        public double T { get; set; }                  // server time of the tick, seconds
        public Vec3[] Positions { get; set; }          // 19 world positions, metres
        public Quat[] Rotations { get; set; }          // 19 world rotations, or null (a v1 pose without rot)
        public bool Keyframe { get; set; }             // v2: the record was a keyframe
        public bool ReachLimited { get; set; }         // v2: the engine limited an arm's reach

        private Quat[] _local;
        /// <summary>Each joint's rotation relative to its parent (PELVIS: world), or null.</summary>
        public Quat[] LocalRotations
        {
            get
            {
                if (_local == null && Rotations != null) _local = Skeleton.WorldToLocal(Rotations);
                return _local;
            }
            internal set { _local = value; }
        }
    }

    public enum EventKind { Welcome, Pose, Presence, Skeleton, Error, Reconnecting, Bad }

    /// <summary>What the server (or the connection) tells the application, in order.</summary>
    public sealed class ClientEvent
    {
        public EventKind Kind;
        public Welcome Welcome;            // Welcome: a join, or a rejoin after a reconnect
        public PlayerPose Pose;            // Pose
        public Presence Presence;          // Presence: join, leave, stale, active
        public SkeletonMessage Skeleton;   // Skeleton (v2): a player's bone offsets changed
        public ErrorMessage Error;         // Error: a non-fatal error message
        public Exception Cause;            // Reconnecting: why; Bad: the ProtocolException
        public int Attempt;                // Reconnecting: 1 for the first try after a loss
        public double DelayS;              // Reconnecting: the wait before it

        public override string ToString()
        {
            switch (Kind)
            {
                case EventKind.Pose: return "Pose(" + Pose.Player + ", seq " + Pose.Seq + ")";
                case EventKind.Presence: return "Presence(" + Presence.Event + ", " + Presence.Player + ")";
                case EventKind.Welcome: return "Welcome(" + Welcome.Player + ", v" + Welcome.Version + ")";
                case EventKind.Error: return "Error(" + Error.Code + ")";
                default: return Kind + "(" + (Cause == null ? "" : Cause.Message) + ")";
            }
        }
    }

    /// <summary>What one server message meant.</summary>
    public sealed class Received
    {
        public readonly List<ClientEvent> Events = new List<ClientEvent>();
        /// <summary>Set when the message ends the session (a fatal error, a bye).</summary>
        public Exception End;
        /// <summary>A message to send back (a resync after a broken record stream), or null.</summary>
        public Message Reply;
    }

    /// <summary>Counters of one client (all connections together).</summary>
    public sealed class Stats
    {
        public long FramesSent, FramesDropped, Poses, Keyframes, Errors, Reconnects, BadMessages, Resyncs, EventsDropped;
    }

    public sealed class ClientSession
    {
        public const double ResyncEveryS = 0.5;

        public readonly ClockSync Clock = new ClockSync();
        public readonly Stats Stats = new Stats();
        public readonly long Seq0;
        public Welcome Welcome { get; private set; }
        /// <summary>The connection's protocol version (1 or 2), set by Connected.</summary>
        public int Version { get; private set; }
        public Limits Limits { get { return Welcome != null ? Welcome.Limits : Limits.Default; } }
        public long? LastSeq { get; private set; }
        public double LastT { get; private set; }

        private readonly Dictionary<long, double> _sentAt = new Dictionary<long, double>();
        private readonly Queue<long> _sentOrder = new Queue<long>();
        private readonly int _rememberFrames;
        // v2: the avatars this connection was told about.
        private readonly Dictionary<long, string> _playerOf = new Dictionary<long, string>();
        private readonly RecordDecoder _records = new RecordDecoder();  // each avatar's skeleton and reference
        private double _lastResync = double.NegativeInfinity;

        public ClientSession(long seq0 = 0, int rememberFrames = 1024)
        {
            Seq0 = seq0;
            _rememberFrames = rememberFrames;
            Version = Protocol.V1;
        }

        // --- outgoing ----------------------------------------------------------------

        /// <summary>The player's tracker set when it joined with one (frames then carry its
        /// sites' rows), else null (the four slots).</summary>
        public TrackerSet Set;

        /// <summary>The hello of this connection's version (pose_rate_hz and forecast_ms are
        /// sent on v2 only; a forecast of 0 is left out).</summary>
        public Hello BuildHello(string token, string room, string name, string layout = null, double? rateHz = null,
                                string[] watch = null, double? poseRateHz = null, double? forecastMs = null)
        {
            bool v2 = Version >= Protocol.V2;
            return new Hello
            {
                Version = Version, Token = token, Room = room, Name = name,
                Layout = layout == "hmd3+waist" ? null : layout, RateHz = rateHz,
                Watch = watch ?? new string[0], PoseRateHz = v2 ? poseRateHz : null,
                ForecastMs = v2 && forecastMs.HasValue && forecastMs.Value != 0.0 ? forecastMs : null,
            };
        }

        /// <summary>Throws ArgumentOutOfRangeException unless 0 &lt;= ms &lt;= 100 (NaN too).</summary>
        public static void CheckForecast(double ms)
        {
            if (!(ms >= 0.0 && ms <= Protocol.MaxForecastMs))
                throw new ArgumentOutOfRangeException("ms", ms, "a forecast is 0 to 100 ms");
        }

        /// <summary>
        /// A checked frame with the next seq and time `now` unless given. Tracked slots:
        /// positions finite within +-1000 m (OutOfRange), orientations finite and not zero
        /// (NotNormalised), then normalised. Untracked slots go as origin + identity.
        /// </summary>
        public Frame BuildFrame(Vec3[] positions, Quat[] orientations, double now, int? valid = null,
                                long? seq = null, double? t = null)
        {
            int mask = valid ?? AllValid;
            Vec3[] pos; Quat[] quat;
            CheckRows(positions, orientations, mask, out pos, out quat);
            long s;
            if (seq == null) s = LastSeq == null ? Seq0 : (LastSeq.Value + 1) & Protocol.UInt32Max;
            else
            {
                s = seq.Value;
                if (s < 0 || s > Protocol.UInt32Max) throw new ArgumentException("seq " + s + " is not a uint32");
                if (LastSeq != null)
                {
                    long d = Protocol.SeqDelta(s, LastSeq.Value);
                    if (d == 0) throw new DuplicateException("seq " + s + " was already sent").At("seq", s);
                    if (d < 0) throw new OutOfOrderException("seq " + s + " after " + LastSeq).At("seq", s);
                }
            }
            double tt = t ?? now;
            if (!(tt >= 0.0 && tt <= Protocol.MaxTimeS && tt >= LastT))
                throw new ArgumentException("frame time " + tt + " s is outside [0, 1e12] or before the last one");
            return new Frame { Seq = s, T = tt, Positions = pos, Orientations = quat, Valid = mask, Sites = Set != null };
        }

        /// <summary>
        /// A checked calibration from one frame of the user standing in a T-pose: every row
        /// (the four slots, or every site of the tracker set) checked as a tracked row of
        /// <see cref="BuildFrame"/> is. A headset-only player's waist slot is not read by the
        /// server; any finite row will do (origin + identity).
        /// </summary>
        public Calibrate BuildTPose(Vec3[] positions, Quat[] orientations)
        {
            Vec3[] pos; Quat[] quat;
            CheckRows(positions, orientations, AllValid, out pos, out quat);
            return new Calibrate { Positions = pos, Orientations = quat, Sites = Set != null };
        }

        // Every row of this player's frames tracked: the four slots', or its set's sites'.
        private int AllValid { get { return Set == null ? Protocol.AllTrackersValid : Set.AllValid; } }

        private void CheckRows(Vec3[] positions, Quat[] orientations, int mask, out Vec3[] pos, out Quat[] quat)
        {
            int rows = Set == null ? Protocol.NumTrackers : Set.Count;
            int full = AllValid;
            string key = Set == null ? "trackers" : "sites";
            if (positions == null || orientations == null || positions.Length != rows || orientations.Length != rows)
                throw new ArgumentException(Set == null
                    ? "need 4 positions and 4 orientations (HEAD, LEFT_HAND, RIGHT_HAND, WAIST)"
                    : "need " + rows + " positions and orientations, one per site of " + Set.Name);
            if (mask < 0 || mask > full) throw new ArgumentException("valid must be in 0.." + full);
            pos = new Vec3[rows];
            quat = new Quat[rows];
            for (int i = 0; i < rows; i++)
            {
                if ((mask >> i & 1) == 0) { pos[i] = Vec3.Zero; quat[i] = Quat.Identity; continue; }
                var p = positions[i];
                if (!(Math.Abs(p.X) <= Protocol.MaxCoordM && Math.Abs(p.Y) <= Protocol.MaxCoordM && Math.Abs(p.Z) <= Protocol.MaxCoordM))
                    throw ErrorCodes.OutOfRange(key + "[" + i + "]", key + "[" + i + "] value " + p);
                double n = orientations[i].Norm;
                if (!(Fields.IsFinite(n) && n > 1e-6))
                    throw ErrorCodes.NotNormalised(key + "[" + i + "]", key + "[" + i + "] orientation " + orientations[i]);
                pos[i] = p;
                quat[i] = orientations[i].Normalised;
            }
        }

        /// <summary>The frame left at client time `now`: its seq and time are taken.</summary>
        public void Sent(Frame f, double now)
        {
            LastSeq = f.Seq; LastT = f.T;
            Stats.FramesSent++;
            _sentAt[f.Seq] = now;
            _sentOrder.Enqueue(f.Seq);
            while (_sentOrder.Count > _rememberFrames) _sentAt.Remove(_sentOrder.Dequeue());
        }

        /// <summary>The frame could not be sent (no connection); its seq is used up all the same.</summary>
        public void Dropped(Frame f)
        {
            LastSeq = f.Seq; LastT = f.T;
            Stats.FramesDropped++;
        }

        /// <summary>Client time the frame `seq` was sent (recent frames only), or null.</summary>
        public double? SentAt(long seq) { double t; return _sentAt.TryGetValue(seq, out t) ? t : (double?)null; }

        // --- incoming ----------------------------------------------------------------

        /// <summary>A new connection speaking `version`: a new server clock, no avatars yet.</summary>
        public void Connected(int version)
        {
            Version = version;
            Clock.Reset();
            ForgetAvatars();
        }

        private void ForgetAvatars()
        {
            _playerOf.Clear(); _records.Clear();
            _lastResync = double.NegativeInfinity;
        }

        private void Announce(string player, long avatarId, byte[] skeleton)
        {
            string had;
            bool fresh = !_playerOf.TryGetValue(avatarId, out had) || had != player;
            // Moved to another avatar id: its old one is gone (as in the Python and TS SDKs).
            if (fresh) ForgetPlayer(player);
            _playerOf[avatarId] = player;
            _records.Announce(avatarId, skeleton, fresh); // fresh: a keyframe comes first
        }

        /// <summary>The players this connection knows, by avatar id (v2), for tests and tools.</summary>
        public IDictionary<long, string> AvatarIds { get { return _playerOf; } }

        /// <summary>What one whole server message means. Never throws for bad input.</summary>
        public Received Receive(byte[] data, double now) { return Receive(data, 0, data.Length, now); }

        public Received Receive(byte[] data, int offset, int count, double now)
        {
            var r = new Received();
            Message msg;
            try { msg = Codec.Decode(data, offset, count, Version, Limits); }
            catch (ProtocolException e)
            {
                Stats.BadMessages++;
                r.Events.Add(new ClientEvent { Kind = EventKind.Bad, Cause = e });
                return r;
            }
            Dispatch(msg, now, r);
            return r;
        }

        private void Dispatch(Message msg, double now, Received r)
        {
            switch (msg.Type)
            {
                case "pose":
                {
                    var p = (Pose)msg;
                    Stats.Poses++;
                    r.Events.Add(new ClientEvent { Kind = EventKind.Pose, Pose = new PlayerPose
                    {
                        Player = p.Player, Seq = p.Seq, T = p.T, Positions = p.Positions, Rotations = p.Rotations,
                    } });
                    break;
                }
                case "poses": DecodePoses((Poses)msg, now, r); break;
                case "pong":
                {
                    var p = (Pong)msg;
                    Clock.Add(p.T0, p.T1, p.T2, now);
                    break;
                }
                case "presence":
                {
                    var p = (Presence)msg;
                    if (Version >= Protocol.V2)
                    {
                        if (p.Event == "join") Announce(p.Player, p.AvatarId.Value, p.Skeleton);
                        else if (p.Event == "leave") ForgetPlayer(p.Player);
                    }
                    r.Events.Add(new ClientEvent { Kind = EventKind.Presence, Presence = p });
                    break;
                }
                case "skeleton":
                {
                    var k = (SkeletonMessage)msg;
                    Announce(k.Player, k.AvatarId, k.Skeleton);
                    r.Events.Add(new ClientEvent { Kind = EventKind.Skeleton, Skeleton = k });
                    break;
                }
                case "welcome":
                {
                    var w = (Welcome)msg;
                    Welcome = w;
                    ForgetAvatars();
                    foreach (var m in w.Members)
                        if (m.AvatarId.HasValue && m.Skeleton != null) Announce(m.Player, m.AvatarId.Value, m.Skeleton);
                    r.Events.Add(new ClientEvent { Kind = EventKind.Welcome, Welcome = w });
                    break;
                }
                case "error":
                {
                    var e = (ErrorMessage)msg;
                    if (e.Fatal) { r.End = e.ToException(); break; }
                    Stats.Errors++;
                    r.Events.Add(new ClientEvent { Kind = EventKind.Error, Error = e });
                    break;
                }
                case "bye":
                {
                    var b = (Bye)msg;
                    r.End = b.Reason == "SERVER_SHUTDOWN"
                        ? (Exception)new ServerShutdownException("the server is shutting down")
                        : new ConnectionLostException("the server said bye (" + (b.Reason ?? "no reason") + ")");
                    break;
                }
                default: break; // client-only types from a confused server: ignore
            }
        }

        private void ForgetPlayer(string player)
        {
            var gone = new List<long>();
            foreach (var kv in _playerOf) if (kv.Value == player) gone.Add(kv.Key);
            foreach (var h in gone) { _playerOf.Remove(h); _records.Forget(h); }
        }

        private void DecodePoses(Poses msg, double now, Received r)
        {
            var poses = new PoseCollector(this, msg.T);
            try { _records.Decode(msg.Data, 0, msg.Data.Length, poses); }
            catch (ProtocolException e)
            {
                // The rest of the message cannot be parsed (records carry no lengths), so the
                // references of the avatars after the bad record are unknown: start over from
                // keyframes, which a resync asks for. None of this message's poses is shown.
                Stats.BadMessages++;
                r.Events.Add(new ClientEvent { Kind = EventKind.Bad, Cause = e });
                _records.DropReferences();
                if (now - _lastResync >= ResyncEveryS)
                {
                    _lastResync = now;
                    Stats.Resyncs++;
                    r.Reply = new Resync();
                }
                return;
            }
            foreach (var pose in poses.Poses)
            {
                Stats.Poses++;
                if (pose.Keyframe) Stats.Keyframes++;
                r.Events.Add(new ClientEvent { Kind = EventKind.Pose, Pose = pose });
            }
        }

        // Each record of one poses message as a PlayerPose of its own (events leave this
        // thread, so the decoder's reused state is copied).
        private sealed class PoseCollector : IRecordSink
        {
            public readonly List<PlayerPose> Poses = new List<PlayerPose>();
            private readonly ClientSession _session;
            private readonly double _t;

            public PoseCollector(ClientSession session, double t) { _session = session; _t = t; }

            public void Record(AvatarState a)
            {
                a.Rebuild();
                var pose = new PlayerPose
                {
                    Player = _session._playerOf[a.AvatarId], Seq = a.Seq, T = _t,
                    Positions = (Vec3[])a.Positions.Clone(), Rotations = (Quat[])a.World.Clone(),
                    Keyframe = a.Keyframe, ReachLimited = a.ReachLimited,
                };
                pose.LocalRotations = (Quat[])a.Items.Clone();
                Poses.Add(pose);
            }
        }

        /// <summary>During a join: the welcome, the error refusing the hello, or null (keep reading).</summary>
        public static object ClassifyJoinReply(Received r)
        {
            foreach (var e in r.Events) if (e.Kind == EventKind.Welcome) return e.Welcome;
            if (r.End != null) return r.End;
            foreach (var e in r.Events) if (e.Kind == EventKind.Error) return e.Error.ToException();
            return null;
        }

        /// <summary>Exponential back-off with jitter: about initial * 2^(attempt-1), capped, drawn from [d/2, d].</summary>
        public static double BackoffDelay(int attempt, double initialS, double maxS, Random rng)
        {
            double d = Math.Min(maxS, initialS * Math.Pow(2.0, Math.Max(0, attempt - 1)));
            return d * (0.5 + 0.5 * rng.NextDouble());
        }

        /// <summary>Whether a session that ended with `cause` is worth reconnecting for.</summary>
        public static bool IsRetryable(Exception cause)
        {
            var p = cause as PosecastException;
            if (p != null) return p.Retryable;
            return cause is System.Net.WebSockets.WebSocketException || cause is System.IO.IOException
                   || cause is System.Net.Sockets.SocketException || cause is TimeoutException;
        }
    }
}
