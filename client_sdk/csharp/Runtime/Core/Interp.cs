// Interpolation: a jitter buffer per player, sampled at any display rate. Pure: the
// caller passes every time. The same rules as the Python and TypeScript SDKs
// (docs/game-engines.md, "Interpolation"), checked on proto/vectors/sdk/interp.json.
//
// At query time `time` a buffer shows tau = time - DelayS on the server's timeline.
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

using System;
using System.Collections.Generic;

namespace Posecast.Client
{
    public enum InterpMode { Interpolate, Extrapolate, Hold }

    /// <summary>How a PoseBuffer smooths; validated once, shared by every buffer.</summary>
    public sealed class InterpConfig
    {
        /// <summary>Render delay, seconds behind the query time (0.1).</summary>
        public readonly double DelayS;
        /// <summary>The longest a pose is carried on past the newest one (0.1 s).</summary>
        public readonly double MaxExtrapolateS;
        /// <summary>A pelvis jump beyond this between consecutive poses snaps (1.0 m).</summary>
        public readonly double TeleportM;
        /// <summary>Consecutive poses further apart than this snap (0.25 s).</summary>
        public readonly double GapS;
        /// <summary>Poses kept per player (32).</summary>
        public readonly int Capacity;
        /// <summary>Time constant over which a correction fades out (0.05 s; 0: at once).</summary>
        public readonly double CorrectionS;

        public InterpConfig(double delayS = 0.1, double maxExtrapolateS = 0.1, double teleportM = 1.0,
                            double gapS = 0.25, int capacity = 32, double correctionS = 0.05)
        {
            foreach (var v in new[] { delayS, maxExtrapolateS, correctionS })
                if (!(Fields.IsFinite(v) && v >= 0.0)) throw new ArgumentException("delay, extrapolation and correction must be finite and >= 0");
            if (!(teleportM > 0.0) || !(gapS > 0.0)) throw new ArgumentException("teleportM and gapS must be > 0");
            if (capacity < 2) throw new ArgumentException("capacity must be >= 2");
            DelayS = delayS; MaxExtrapolateS = maxExtrapolateS; TeleportM = teleportM; GapS = gapS;
            Capacity = capacity; CorrectionS = correctionS;
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

    /// <summary>One player's pose as shown at T (the query time minus the delay).</summary>
    public sealed class InterpolatedPose
    {
        public string Player;
        public double T;
        public long Seq;
        public Vec3[] Positions;
        public Quat[] Rotations;   // unit, or null when the poses had none
        public InterpMode Mode;
    }

    /// <summary>The jitter buffer of one player.</summary>
    public sealed class PoseBuffer
    {
        private struct Entry
        {
            public double T;
            public long Seq;
            public bool Keyframe;
            public Vec3[] Positions;
            public Quat[] Rotations;
        }

        public readonly InterpConfig Config;
        public string Player { get; private set; }
        private readonly List<Entry> _entries = new List<Entry>(); // sorted by T, no two alike
        private InterpolatedPose _last;

        public PoseBuffer(InterpConfig config = null) { Config = config ?? InterpConfig.Default; }

        public int Count { get { return _entries.Count; } }
        public double? NewestT { get { return _entries.Count == 0 ? (double?)null : _entries[_entries.Count - 1].T; } }

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
        /// not newer than its predecessor's (a new sequence).
        /// </summary>
        public bool Push(IPose pose, bool keyframe)
        {
            double t = pose.T;
            if (!Fields.IsFinite(t)) return false;
            int i = Bisect(t, false);
            if (i < _entries.Count && _entries[i].T == t) return false;
            if (i == 0 && _entries.Count >= Config.Capacity) return false;
            Player = pose.Player;
            _entries.Insert(i, new Entry
            {
                T = t, Seq = pose.Seq, Keyframe = keyframe,
                Positions = (Vec3[])pose.Positions.Clone(),
                Rotations = pose.Rotations == null ? null : (Quat[])pose.Rotations.Clone(),
            });
            if (_entries.Count > Config.Capacity) _entries.RemoveAt(0);
            return true;
        }

        public bool Push(IPose pose) { return Push(pose, pose.Keyframe); }

        /// <summary>Forget every pose (after a reconnect the server's clock may differ).</summary>
        public void Clear() { _entries.Clear(); _last = null; }

        /// <summary>
        /// The pose shown at server time `time`, or null before the first pose. Call once
        /// per displayed frame with times that do not go back (rule 5 fades corrections).
        /// </summary>
        public InterpolatedPose PoseAt(double time)
        {
            double tau = time - Config.DelayS;
            var raw = Raw(tau);
            var last = _last;
            _last = null;
            if (raw == null) return null;
            var shown = raw;
            if (last != null && Blends(last.T, tau))
            {
                var before = Raw(last.T);
                double k = Math.Exp(-(tau - last.T) / Config.CorrectionS);
                var pos = new Vec3[raw.Positions.Length];
                for (int j = 0; j < pos.Length; j++)
                    pos[j] = raw.Positions[j] + (last.Positions[j] - before.Positions[j]) * k;
                var rot = raw.Rotations;
                if (rot != null && last.Rotations != null && before.Rotations != null)
                {
                    var corrected = new Quat[rot.Length];
                    for (int j = 0; j < rot.Length; j++)
                    {
                        var off = last.Rotations[j] * before.Rotations[j].Conjugate;
                        corrected[j] = Quat.Slerp(Quat.Identity, off, k) * rot[j];
                    }
                    rot = corrected;
                }
                shown = new InterpolatedPose { Player = raw.Player, T = tau, Seq = raw.Seq, Positions = pos, Rotations = rot, Mode = raw.Mode };
            }
            _last = shown;
            return shown;
        }

        /// <summary>The pose at server time `time` from the poses kept now (rules 1-4, no memory).</summary>
        public InterpolatedPose SampleAt(double time) { return Raw(time - Config.DelayS); }

        private bool Blends(double lastTau, double tau)
        {
            if (Config.CorrectionS == 0.0 || !(0.0 < tau - lastTau && tau - lastTau <= Config.GapS)) return false;
            int lo = Bisect(lastTau, true), hi = Bisect(tau, true);
            for (int k = Math.Max(lo, 1); k < hi; k++)
                if (Snaps(_entries[k - 1], _entries[k])) return false;
            return true;
        }

        private InterpolatedPose Raw(double tau)
        {
            if (_entries.Count == 0) return null;
            int i = Bisect(tau, true) - 1;
            if (i < 0) return Hold(_entries[0], tau);
            var a = _entries[i];
            if (i + 1 < _entries.Count)
            {
                var b = _entries[i + 1];
                if (!Snaps(a, b))
                {
                    double u = (tau - a.T) / (b.T - a.T);
                    var pos = new Vec3[a.Positions.Length];
                    for (int j = 0; j < pos.Length; j++) pos[j] = Vec3.Lerp(a.Positions[j], b.Positions[j], u);
                    Quat[] rot = null;
                    if (a.Rotations != null && b.Rotations != null)
                    {
                        rot = new Quat[a.Rotations.Length];
                        for (int j = 0; j < rot.Length; j++) rot[j] = Quat.Slerp(a.Rotations[j], b.Rotations[j], u);
                    }
                    return Sample(a, tau, pos, InterpMode.Interpolate, rot);
                }
            }
            // a is the newest pose of its segment: carry it on, then hold.
            if (i == 0 || Snaps(_entries[i - 1], a) || Config.MaxExtrapolateS == 0.0) return Hold(a, tau);
            var p = _entries[i - 1];
            double ahead = tau - a.T;
            var mode = ahead <= Config.MaxExtrapolateS ? InterpMode.Extrapolate : InterpMode.Hold;
            double s = Math.Min(ahead, Config.MaxExtrapolateS) / (a.T - p.T);
            var epos = new Vec3[a.Positions.Length];
            for (int j = 0; j < epos.Length; j++) epos[j] = a.Positions[j] + (a.Positions[j] - p.Positions[j]) * s;
            Quat[] erot = null;
            if (a.Rotations != null && p.Rotations != null)
            {
                erot = new Quat[a.Rotations.Length];
                for (int j = 0; j < erot.Length; j++) erot[j] = Quat.Slerp(p.Rotations[j], a.Rotations[j], 1.0 + s);
            }
            return Sample(a, tau, epos, mode, erot);
        }

        private bool Snaps(Entry a, Entry b)
        {
            if (b.T - a.T > Config.GapS) return true;
            if (b.Keyframe && Protocol.SeqDelta(b.Seq, a.Seq) <= 0) return true;
            return (b.Positions[0] - a.Positions[0]).Length > Config.TeleportM;
        }

        private InterpolatedPose Hold(Entry a, double tau)
        {
            Quat[] rot = null;
            if (a.Rotations != null)
            {
                rot = new Quat[a.Rotations.Length];
                for (int j = 0; j < rot.Length; j++) rot[j] = a.Rotations[j].Normalised;
            }
            return Sample(a, tau, (Vec3[])a.Positions.Clone(), InterpMode.Hold, rot);
        }

        private InterpolatedPose Sample(Entry a, double tau, Vec3[] pos, InterpMode mode, Quat[] rot)
        {
            return new InterpolatedPose { Player = Player ?? "", T = tau, Seq = a.Seq, Positions = pos, Rotations = rot, Mode = mode };
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

        /// <summary>A player's pose shown at server time `time`, or null if unknown.</summary>
        public InterpolatedPose PoseAt(string player, double time)
        {
            var b = Buffer(player);
            return b == null ? null : b.PoseAt(time);
        }

        /// <summary>Every known player's pose shown at server time `time`.</summary>
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
    }
}
