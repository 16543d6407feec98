// Interpolation: a jitter buffer per player, sampled at any display rate. Pure: the
// caller passes every time. The same rules as the Python and TypeScript SDKs
// (docs/game-engines.md, "Interpolation"), checked on proto/vectors/sdk/interp.json and,
// for the adaptive render delay (RenderDelay.cs), on delay.json.
//
// At query time `time` a buffer shows tau = time - delay on the server's timeline: the
// delay follows the measured arrival jitter (Adaptive, the default: the smallest delay
// at which 99 % of recent pose intervals interpolate, within MinDelayS..MaxDelayS,
// changing by at most 5 % of real time), or stays DelayS (Adaptive false).
// With a the newest pose at or before tau and b the one after it:
//   1. interpolate: positions lerp and rotations slerp (shortest arc) from a to b;
//   2. snap: b starts a new segment when its pelvis moved more than TeleportM from a,
//      follows a by more than GapS, or is a keyframe whose seq is not newer than a's;
//      nothing is blended across a segment start;
//   3. extrapolate: past the newest pose, a moves on at the velocity from its
//      predecessor for at most MaxExtrapolateS, then holds there;
//   4. hold: before the first pose, and from a pose with no predecessor in its segment;
//   5. correct smoothly: PoseAt remembers what it showed last; when poses that arrived
//      since change that answer, the difference fades as exp(-dt / CorrectionS).
// Memory is bounded: Capacity poses per player, MaxPlayers buffers per Interpolator.
// Without garbage: PoseAt(time, into) and PosesAt(time, into) write into caller-owned
// InterpolatedPose objects (their arrays reused), and Push reuses the evicted pose's
// arrays, so a steady stream allocates nothing per frame (a GC hitch on Quest);
// PoseAt(time) and PosesAt(time) allocate fresh ones.

using System;
using System.Collections.Generic;

namespace Posecast.Client
{
    public enum InterpMode { Interpolate, Extrapolate, Hold }

    /// <summary>How a PoseBuffer smooths; validated once, shared by every buffer.</summary>
    public sealed class InterpConfig
    {
        /// <summary>The fixed render delay, seconds behind the query time (0.1), and the adaptive one's start.</summary>
        public readonly double DelayS;
        /// <summary>The longest a pose is carried on past the newest one (0.1 s).</summary>
        public readonly double MaxExtrapolateS;
        /// <summary>A pelvis jump beyond this between consecutive poses snaps (1.0 m).</summary>
        public readonly double TeleportM;
        /// <summary>Consecutive poses further apart than this snap, and count toward no delay (0.25 s).</summary>
        public readonly double GapS;
        /// <summary>Poses kept per player (32).</summary>
        public readonly int Capacity;
        /// <summary>Time constant over which a correction fades out (0.05 s; 0: at once).</summary>
        public readonly double CorrectionS;
        /// <summary>The render delay follows the measured arrival jitter (true); false: it stays DelayS.</summary>
        public readonly bool Adaptive;
        /// <summary>The adaptive delay's bounds (0.02 s, a bit above a 60 Hz pose interval; 0.25 s).</summary>
        public readonly double MinDelayS, MaxDelayS;
        /// <summary>The share of recent pose intervals it lets interpolate whole (0.99, nearest rank).</summary>
        public readonly double DelayQuantile;
        /// <summary>The recent poses it measures (256: about 4 s at 60 Hz).</summary>
        public readonly int DelayWindow;
        /// <summary>Added to that quantile (0.002 s).</summary>
        public readonly double DelayMarginS;
        /// <summary>The most it changes per second of query time (0.05: shown time at 0.95 to 1.05 of real speed).</summary>
        public readonly double DelaySlew;

        public InterpConfig(double delayS = 0.1, double maxExtrapolateS = 0.1, double teleportM = 1.0,
                            double gapS = 0.25, int capacity = 32, double correctionS = 0.05,
                            bool adaptive = true, double minDelayS = 0.02, double maxDelayS = 0.25,
                            double delayQuantile = 0.99, int delayWindow = 256, double delayMarginS = 0.002,
                            double delaySlew = 0.05)
        {
            foreach (var v in new[] { delayS, maxExtrapolateS, correctionS, minDelayS, maxDelayS, delayMarginS, delaySlew })
                if (!(Fields.IsFinite(v) && v >= 0.0)) throw new ArgumentException("delays, extrapolation, correction, margin and slew must be finite and >= 0");
            if (!(teleportM > 0.0) || !(gapS > 0.0)) throw new ArgumentException("teleportM and gapS must be > 0");
            if (capacity < 2) throw new ArgumentException("capacity must be >= 2");
            if (minDelayS > maxDelayS) throw new ArgumentException("minDelayS must be <= maxDelayS");
            if (!(delayQuantile > 0.0 && delayQuantile <= 1.0)) throw new ArgumentException("delayQuantile must be in (0, 1]");
            if (delayWindow < 1) throw new ArgumentException("delayWindow must be >= 1");
            DelayS = delayS; MaxExtrapolateS = maxExtrapolateS; TeleportM = teleportM; GapS = gapS;
            Capacity = capacity; CorrectionS = correctionS; Adaptive = adaptive; MinDelayS = minDelayS;
            MaxDelayS = maxDelayS; DelayQuantile = delayQuantile; DelayWindow = delayWindow;
            DelayMarginS = delayMarginS; DelaySlew = delaySlew;
        }

        public static readonly InterpConfig Default = new InterpConfig();
    }

    /// <summary>A pose as buffers read it; PlayerPose (what sessions emit) is one.</summary>
    public interface IPose
    {
        string Player { get; }
        long Seq { get; }
        double T { get; }
        Vec3[] Positions { get; }
        Quat[] Rotations { get; }   // world rotations, or null
        bool Keyframe { get; }
    }

    /// <summary>
    /// One player's pose as shown at T (the query time minus the delay). PoseAt(time, into)
    /// fills a caller-owned one in place, reusing its arrays while the joint count stays.
    /// </summary>
    public sealed class InterpolatedPose
    {
        public string Player;
        public double T;
        public long Seq;
        public Vec3[] Positions;
        public Quat[] Rotations;   // unit, or null when the poses had none
        public InterpMode Mode;
        internal long Frame = -1;  // the Interpolator frame that last filled it

        // Arrays for nPos positions and nRot rotations (-1: none), reused when they fit.
        internal void Shape(int nPos, int nRot)
        {
            if (Positions == null || Positions.Length != nPos) Positions = new Vec3[nPos];
            if (nRot < 0) Rotations = null;
            else if (Rotations == null || Rotations.Length != nRot) Rotations = new Quat[nRot];
        }

        internal void CopyFrom(InterpolatedPose o)
        {
            Shape(o.Positions.Length, o.Rotations == null ? -1 : o.Rotations.Length);
            Player = o.Player; T = o.T; Seq = o.Seq; Mode = o.Mode;
            Array.Copy(o.Positions, Positions, Positions.Length);
            if (o.Rotations != null) Array.Copy(o.Rotations, Rotations, Rotations.Length);
        }
    }

    /// <summary>The jitter buffer of one player.</summary>
    public sealed class PoseBuffer
    {
        private sealed class Entry
        {
            public double T;
            public long Seq;
            public bool Keyframe;
            public bool Seen;          // a query ran since it was pushed (its need is counted)
            public Vec3[] Positions;
            public Quat[] Rotations;
        }

        public readonly InterpConfig Config;
        public string Player { get; private set; }
        private readonly List<Entry> _entries; // sorted by T, no two alike
        private readonly RenderDelay _delay;
        private int _unseen;                    // entries pushed since the last PoseAt
        private readonly InterpolatedPose _last = new InterpolatedPose(); // what PoseAt showed last, while _hasLast
        private bool _hasLast;
        private readonly InterpolatedPose _before = new InterpolatedPose(); // rule 5's scratch

        public PoseBuffer(InterpConfig config = null)
        {
            Config = config ?? InterpConfig.Default;
            _entries = new List<Entry>(Config.Capacity + 1);
            _delay = new RenderDelay(Config.DelayS, Config.MinDelayS, Config.MaxDelayS, Config.DelayQuantile,
                                     Config.DelayWindow, Config.DelayMarginS, Config.DelaySlew);
        }

        public int Count { get { return _entries.Count; } }
        public double? NewestT { get { return _entries.Count == 0 ? (double?)null : _entries[_entries.Count - 1].T; } }

        /// <summary>The render delay now, seconds: Config.DelayS when not adaptive.</summary>
        public double DelayS { get { return Config.Adaptive ? _delay.DelayS : Config.DelayS; } }

        /// <summary>The delay the adaptive delay moves toward (null before it measured a pose interval, and when not adaptive).</summary>
        public double? TargetDelayS { get { return Config.Adaptive ? _delay.TargetS : null; } }

        /// <summary>
        /// The server time the last PoseAt showed (its tau); null before it showed a pose. A
        /// received pose is first on screen at the first frame whose ShownT reaches its T.
        /// </summary>
        public double? ShownT { get { return _hasLast ? _last.T : (double?)null; } }

        // The first index whose T is > t (bisect_right) or >= t (bisect_left).
        private int Bisect(double t, bool right)
        {
            int lo = 0, hi = _entries.Count;
            while (lo < hi)
            {
                int mid = (lo + hi) / 2;
                if (right ? _entries[mid].T <= t : _entries[mid].T < t) lo = mid + 1; else hi = mid;
            }
            return lo;
        }

        /// <summary>
        /// Keep a pose; false when dropped: a duplicate of a kept T, a non-finite T, or older
        /// than everything kept while full. keyframe: a resync point that snaps when its seq is
        /// not newer than its predecessor's (a new sequence). Once full, the oldest pose's
        /// arrays are reused for the new one.
        /// </summary>
        public bool Push(IPose pose, bool keyframe)
        {
            double t = pose.T;
            if (!Fields.IsFinite(t)) return false;
            int i = Bisect(t, false);
            if (i < _entries.Count && _entries[i].T == t) return false;
            if (i == 0 && _entries.Count >= Config.Capacity) return false;
            Player = pose.Player;
            Entry e;
            if (_entries.Count >= Config.Capacity)
            {
                e = _entries[0]; // the oldest goes (i >= 1 here): reuse its arrays
                if (!e.Seen) _unseen--;
                _entries.RemoveAt(0);
                i--;
            }
            else e = new Entry();
            e.T = t; e.Seq = pose.Seq; e.Keyframe = keyframe; e.Seen = false;
            e.Positions = Fit(e.Positions, pose.Positions);
            e.Rotations = pose.Rotations == null ? null : Fit(e.Rotations, pose.Rotations);
            _entries.Insert(i, e);
            _unseen++;
            return true;
        }

        public bool Push(IPose pose) { return Push(pose, pose.Keyframe); }

        // dst holding a copy of src: dst itself when the lengths match.
        private static TV[] Fit<TV>(TV[] dst, TV[] src)
        {
            if (dst == null || dst.Length != src.Length) return (TV[])src.Clone();
            Array.Copy(src, dst, src.Length);
            return dst;
        }

        /// <summary>Forget every pose (after a reconnect the server's clock may differ).</summary>
        public void Clear() { _entries.Clear(); _hasLast = false; _unseen = 0; _delay.Reset(); }

        /// <summary>
        /// The pose shown at server time `time`, or null before the first pose. Call once
        /// per displayed frame with times that do not go back (rule 5 fades corrections;
        /// adaptive, the poses pushed since the last call count as arrived at `time`).
        /// Allocates the result: PoseAt(time, into) does not.
        /// </summary>
        public InterpolatedPose PoseAt(double time)
        {
            var into = new InterpolatedPose();
            return PoseAt(time, into) ? into : null;
        }

        /// <summary>PoseAt written into `into` (its arrays reused); false, `into` untouched: no pose yet.</summary>
        public bool PoseAt(double time, InterpolatedPose into)
        {
            if (Config.Adaptive)
            {
                Observe(time);
                _delay.Advance(time);
            }
            double tau = time - DelayS;
            bool hadLast = _hasLast;
            _hasLast = false;
            if (!RawInto(tau, into)) return false;
            if (hadLast && Blends(_last.T, tau))
            {
                var before = _before; // what the last frame would show with today's poses
                RawInto(_last.T, before);
                double k = Math.Exp(-(tau - _last.T) / Config.CorrectionS);
                var pos = into.Positions;
                for (int j = 0; j < pos.Length; j++)
                    pos[j] = pos[j] + (_last.Positions[j] - before.Positions[j]) * k;
                var rot = into.Rotations;
                if (rot != null && _last.Rotations != null && before.Rotations != null)
                {
                    for (int j = 0; j < rot.Length; j++)
                    {
                        var off = _last.Rotations[j] * before.Rotations[j].Conjugate;
                        rot[j] = Quat.Slerp(Quat.Identity, off, k) * rot[j];
                    }
                }
            }
            _last.CopyFrom(into);
            _hasLast = true;
            return true;
        }

        /// <summary>The pose at server time `time` from the poses kept now (rules 1-4, no memory), at the current delay.</summary>
        public InterpolatedPose SampleAt(double time)
        {
            var into = new InterpolatedPose();
            return RawInto(time - DelayS, into) ? into : null;
        }

        // Each pose pushed since the last query arrived, for the display, at `time`.
        private void Observe(double time)
        {
            if (_unseen == 0) return;
            double gap = Config.GapS;
            bool measures = _delay.Measures(time, gap);
            for (int k = 0; k < _entries.Count; k++)
            {
                var e = _entries[k];
                if (e.Seen) continue;
                e.Seen = true;
                if (measures && k > 0 && e.T - _entries[k - 1].T <= gap) _delay.Observe(time - _entries[k - 1].T);
            }
            _unseen = 0;
        }

        private bool Blends(double lastTau, double tau)
        {
            if (Config.CorrectionS == 0.0 || !(0.0 < tau - lastTau && tau - lastTau <= Config.GapS)) return false;
            int lo = Bisect(lastTau, true), hi = Bisect(tau, true);
            for (int k = Math.Max(lo, 1); k < hi; k++)
                if (Snaps(_entries[k - 1], _entries[k])) return false;
            return true;
        }

        // Rules 1 to 4 at tau, into `o`; false while empty.
        private bool RawInto(double tau, InterpolatedPose o)
        {
            if (_entries.Count == 0) return false;
            int i = Bisect(tau, true) - 1;
            if (i < 0) return Hold(_entries[0], tau, o);
            var a = _entries[i];
            int n = a.Positions.Length;
            if (i + 1 < _entries.Count)
            {
                var b = _entries[i + 1];
                if (!Snaps(a, b))
                {
                    double u = (tau - a.T) / (b.T - a.T);
                    Head(o, a, tau, InterpMode.Interpolate, a.Rotations != null && b.Rotations != null);
                    for (int j = 0; j < n; j++) o.Positions[j] = Vec3.Lerp(a.Positions[j], b.Positions[j], u);
                    if (o.Rotations != null)
                        for (int j = 0; j < o.Rotations.Length; j++) o.Rotations[j] = Quat.Slerp(a.Rotations[j], b.Rotations[j], u);
                    return true;
                }
            }
            // a is the newest pose of its segment: carry it on, then hold.
            if (i == 0 || Snaps(_entries[i - 1], a) || Config.MaxExtrapolateS == 0.0) return Hold(a, tau, o);
            var p = _entries[i - 1];
            double ahead = tau - a.T;
            var mode = ahead <= Config.MaxExtrapolateS ? InterpMode.Extrapolate : InterpMode.Hold;
            double s = Math.Min(ahead, Config.MaxExtrapolateS) / (a.T - p.T);
            Head(o, a, tau, mode, a.Rotations != null && p.Rotations != null);
            for (int j = 0; j < n; j++) o.Positions[j] = a.Positions[j] + (a.Positions[j] - p.Positions[j]) * s;
            if (o.Rotations != null)
                for (int j = 0; j < o.Rotations.Length; j++) o.Rotations[j] = Quat.Slerp(p.Rotations[j], a.Rotations[j], 1.0 + s);
            return true;
        }

        private bool Snaps(Entry a, Entry b)
        {
            if (b.T - a.T > Config.GapS) return true;
            if (b.Keyframe && Protocol.SeqDelta(b.Seq, a.Seq) <= 0) return true;
            return (b.Positions[0] - a.Positions[0]).Length > Config.TeleportM;
        }

        private bool Hold(Entry a, double tau, InterpolatedPose o)
        {
            Head(o, a, tau, InterpMode.Hold, a.Rotations != null);
            Array.Copy(a.Positions, o.Positions, a.Positions.Length);
            if (o.Rotations != null)
                for (int j = 0; j < o.Rotations.Length; j++) o.Rotations[j] = a.Rotations[j].Normalised;
            return true;
        }

        // `o` shaped like `a` (rotations sized as a's when `rot`), its scalars set.
        private void Head(InterpolatedPose o, Entry a, double tau, InterpMode mode, bool rot)
        {
            o.Shape(a.Positions.Length, rot ? a.Rotations.Length : -1);
            o.Player = Player ?? ""; o.T = tau; o.Seq = a.Seq; o.Mode = mode;
        }
    }

    /// <summary>A PoseBuffer per player, created on a player's first pose.</summary>
    public sealed class Interpolator
    {
        public readonly InterpConfig Config;
        public readonly int MaxPlayers;
        // Least recently heard from first.
        private readonly LinkedList<KeyValuePair<string, PoseBuffer>> _order = new LinkedList<KeyValuePair<string, PoseBuffer>>();
        private readonly Dictionary<string, LinkedListNode<KeyValuePair<string, PoseBuffer>>> _buffers =
            new Dictionary<string, LinkedListNode<KeyValuePair<string, PoseBuffer>>>();
        private long _frame;                                     // PosesAt(time, into) calls
        private readonly List<string> _stale = new List<string>(); // its scratch

        public Interpolator(InterpConfig config = null, int maxPlayers = 512)
        {
            if (maxPlayers < 1) throw new ArgumentException("maxPlayers must be >= 1");
            Config = config ?? InterpConfig.Default;
            MaxPlayers = maxPlayers;
        }

        public IEnumerable<string> Players { get { foreach (var kv in _order) yield return kv.Key; } }

        public PoseBuffer Buffer(string player)
        {
            LinkedListNode<KeyValuePair<string, PoseBuffer>> node;
            return _buffers.TryGetValue(player, out node) ? node.Value.Value : null;
        }

        /// <summary>Route a pose to its player's buffer (see PoseBuffer.Push).</summary>
        public bool Push(IPose pose)
        {
            LinkedListNode<KeyValuePair<string, PoseBuffer>> node;
            if (!_buffers.TryGetValue(pose.Player, out node))
            {
                node = _order.AddLast(new KeyValuePair<string, PoseBuffer>(pose.Player, new PoseBuffer(Config)));
                _buffers[pose.Player] = node;
                while (_buffers.Count > MaxPlayers)
                {
                    _buffers.Remove(_order.First.Value.Key);
                    _order.RemoveFirst();
                }
            }
            else
            {
                _order.Remove(node);
                _order.AddLast(node);
            }
            return node.Value.Value.Push(pose);
        }

        /// <summary>Take any client event: a pose is pushed, a leave forgets its player, a welcome clears all.</summary>
        public void Feed(ClientEvent e)
        {
            if (e.Pose != null) Push(e.Pose);
            else if (e.Presence != null && e.Presence.Event == "leave") Forget(e.Presence.Player);
            else if (e.Welcome != null) Clear();
        }

        public void Forget(string player)
        {
            LinkedListNode<KeyValuePair<string, PoseBuffer>> node;
            if (_buffers.TryGetValue(player, out node)) { _order.Remove(node); _buffers.Remove(player); }
        }

        public void Clear() { _order.Clear(); _buffers.Clear(); }

        /// <summary>A player's pose shown at server time `time`, or null if unknown (allocates the result).</summary>
        public InterpolatedPose PoseAt(string player, double time)
        {
            var b = Buffer(player);
            return b == null ? null : b.PoseAt(time);
        }

        /// <summary>A player's pose shown at server time `time`, written into `into`; false if unknown or no pose yet.</summary>
        public bool PoseAt(string player, double time, InterpolatedPose into)
        {
            var b = Buffer(player);
            return b != null && b.PoseAt(time, into);
        }

        /// <summary>Every known player's pose shown at server time `time` (allocates: see PosesAt(time, into)).</summary>
        public Dictionary<string, InterpolatedPose> PosesAt(double time)
        {
            var out_ = new Dictionary<string, InterpolatedPose>();
            foreach (var kv in _order)
            {
                var shown = kv.Value.PoseAt(time);
                if (shown != null) out_[kv.Key] = shown;
            }
            return out_;
        }

        /// <summary>
        /// PosesAt without garbage once warm: every known player's pose at `time` written into
        /// `into`'s InterpolatedPose for that player (one is made the first time a player
        /// shows); players no longer shown leave `into`. Keep `into` from frame to frame.
        /// Returns the number of players shown.
        /// </summary>
        public int PosesAt(double time, Dictionary<string, InterpolatedPose> into)
        {
            _frame++;
            int shown = 0;
            foreach (var kv in _order)
            {
                InterpolatedPose pose;
                if (!into.TryGetValue(kv.Key, out pose)) { pose = new InterpolatedPose(); into[kv.Key] = pose; }
                if (kv.Value.PoseAt(time, pose)) { pose.Frame = _frame; shown++; }
            }
            if (into.Count > shown)
            {
                _stale.Clear();
                foreach (var kv in into) if (kv.Value.Frame != _frame) _stale.Add(kv.Key);
                for (int k = 0; k < _stale.Count; k++) into.Remove(_stale[k]);
            }
            return shown;
        }
    }
}
