// A recording of tracker frames (the four slots: HEAD, LEFT_HAND, RIGHT_HAND, WAIST),
// replayed as a headset would stream it: the Unity sample's desktop mode, tests, tools.
// Pure: text in, frames out. Format (one frame a line, '#' lines are comments):
//
//   t_s, valid, then per slot px, py, pz (metres), qx, qy, qz, qw   (30 numbers)
//
// in posecast's frame (right-handed, +Y up, the floor at y = 0), times increasing.
// Tests~/make_recording.py writes one from the Python SDK's walk.

using System;
using System.Collections.Generic;
using System.Globalization;

namespace Posecast.Client
{
    public sealed class TrackerRecording
    {
        private const int Columns = 2 + Protocol.NumTrackers * 7;
        private readonly double[] _t;
        private readonly int[] _valid;
        private readonly Vec3[] _pos;   // frame-major: NumTrackers per frame
        private readonly Quat[] _rot;

        private TrackerRecording(double[] t, int[] valid, Vec3[] pos, Quat[] rot) { _t = t; _valid = valid; _pos = pos; _rot = rot; }

        public int Count { get { return _t.Length; } }
        /// <summary>Seconds from the first frame to one frame past the last (the loop's length).</summary>
        public double DurationS { get; private set; }

        /// <summary>Parse a recording; FormatException (with the line number) for anything else.</summary>
        public static TrackerRecording Parse(string text)
        {
            var t = new List<double>();
            var valid = new List<int>();
            var pos = new List<Vec3>();
            var rot = new List<Quat>();
            var lines = text.Split('\n');
            for (int n = 0; n < lines.Length; n++)
            {
                var line = lines[n].Trim();
                if (line.Length == 0 || line[0] == '#') continue;
                var cells = line.Split(',');
                if (cells.Length != Columns) throw new FormatException("line " + (n + 1) + ": " + cells.Length + " values, not " + Columns);
                var v = new double[Columns];
                for (int i = 0; i < Columns; i++)
                    if (!double.TryParse(cells[i], NumberStyles.Float, CultureInfo.InvariantCulture, out v[i]) || !Fields.IsFinite(v[i]))
                        throw new FormatException("line " + (n + 1) + ": value " + (i + 1) + " (" + cells[i].Trim() + ") is not a finite number");
                if (t.Count > 0 && !(v[0] > t[t.Count - 1])) throw new FormatException("line " + (n + 1) + ": time " + v[0] + " s does not increase");
                if (v[1] != Math.Floor(v[1]) || v[1] < 0 || v[1] > Protocol.AllTrackersValid)
                    throw new FormatException("line " + (n + 1) + ": valid " + v[1] + " is not 0.." + Protocol.AllTrackersValid);
                t.Add(v[0]);
                valid.Add((int)v[1]);
                for (int s = 0; s < Protocol.NumTrackers; s++)
                {
                    int at = 2 + 7 * s;
                    pos.Add(new Vec3(v[at], v[at + 1], v[at + 2]));
                    rot.Add(new Quat(v[at + 3], v[at + 4], v[at + 5], v[at + 6]));
                }
            }
            if (t.Count < 2) throw new FormatException("a recording needs at least 2 frames, got " + t.Count);
            var r = new TrackerRecording(t.ToArray(), valid.ToArray(), pos.ToArray(), rot.ToArray());
            r.DurationS = t[t.Count - 1] - t[0] + (t[t.Count - 1] - t[0]) / (t.Count - 1);
            return r;
        }

        /// <summary>
        /// The frame shown `elapsedS` seconds into the replay (the latest at or before it;
        /// looped), copied into pos and rot (4 each), moved by `offset`; returns its valid bits.
        /// Allocates nothing.
        /// </summary>
        public int FrameAt(double elapsedS, Vec3[] pos, Quat[] rot, Vec3 offset)
        {
            double u = elapsedS % DurationS;
            if (u < 0) u += DurationS;
            u += _t[0];
            int lo = 0, hi = _t.Length - 1;
            while (lo < hi)
            {
                int mid = (lo + hi + 1) / 2;
                if (_t[mid] <= u) lo = mid; else hi = mid - 1;
            }
            for (int s = 0; s < Protocol.NumTrackers; s++)
            {
                pos[s] = _pos[lo * Protocol.NumTrackers + s] + offset;
                rot[s] = _rot[lo * Protocol.NumTrackers + s];
            }
            return _valid[lo];
        }
    }
}
