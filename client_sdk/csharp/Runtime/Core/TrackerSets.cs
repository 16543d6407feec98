// Tracker sets (proto/README.md, hello `layout`; the server's posecast.tracking.sites):
// a layout listing body sites in the order a player's `frame.sites` rows come in, an
// inertial (IMU) site suffixed ":imu", e.g.
// "head,left_hand,right_hand,waist,left_foot:imu,right_foot:imu". A positional row
// carries the world position in metres, an inertial row the world acceleration with
// gravity removed (m/s^2); both carry the world orientation. Head and both hands are
// required and positional.
using System;
using System.Collections.Generic;

namespace Posecast.Client
{
    public sealed class TrackerSet
    {
        /// <summary>The ten sites, in the model's row order.</summary>
        public static readonly string[] AllSites = {
            "head", "left_hand", "right_hand", "waist", "left_foot", "right_foot",
            "left_knee", "right_knee", "left_elbow", "right_elbow",
        };
        public const int MaxSites = 10;
        public const int MaxLayoutBytes = 128;
        public const string InertialSuffix = ":imu";
        private static readonly string[] Required = { "head", "left_hand", "right_hand" };

        public readonly string Name;
        public readonly string[] Sites;
        public readonly bool[] Inertial;

        private TrackerSet(string name, string[] sites, bool[] inertial)
        {
            Name = name; Sites = sites; Inertial = inertial;
        }

        public int Count { get { return Sites.Length; } }

        /// <summary>frame.valid with every row tracked.</summary>
        public int AllValid { get { return (1 << Sites.Length) - 1; } }

        /// <summary>The set `text` names; ArgumentException says why not (the server's rule).</summary>
        public static TrackerSet Parse(string text)
        {
            if (string.IsNullOrEmpty(text)) throw new ArgumentException("a tracker set is a non-empty string");
            var sites = new List<string>();
            var inertial = new List<bool>();
            foreach (var token in text.Split(','))
            {
                bool imu = token.EndsWith(InertialSuffix, StringComparison.Ordinal);
                string name = imu ? token.Substring(0, token.Length - InertialSuffix.Length) : token;
                if (Array.IndexOf(AllSites, name) < 0) throw new ArgumentException("unknown site '" + name + "'");
                if (sites.Contains(name)) throw new ArgumentException("site '" + name + "' listed twice");
                sites.Add(name);
                inertial.Add(imu);
            }
            foreach (var site in Required)
            {
                int i = sites.IndexOf(site);
                if (i < 0 || inertial[i])
                    throw new ArgumentException("a tracker set needs a " + (i < 0 ? "" : "positional ") + "'" + site + "' tracker");
            }
            return new TrackerSet(text, sites.ToArray(), inertial.ToArray());
        }

        /// <summary>The set a hello layout names, or null for a named layout (or none).</summary>
        public static TrackerSet Of(string layout)
        {
            if (layout == null || Array.IndexOf(Protocol.Layouts, layout) >= 0) return null;
            return Parse(layout);
        }
    }
}
