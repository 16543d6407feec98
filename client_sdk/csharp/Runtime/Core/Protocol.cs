// The wire's constants, limits, joints and tracker slots (proto/README.md and
// proto/fields.json are the spec; a test compares these with fields.json).
//
// Units everywhere: metres, seconds, hertz; a right-handed world with +Y up where a
// character faces +Z and its left is +X; quaternions xyzw.

using System;
using System.Collections.Generic;

namespace Posecast.Client
{
    /// <summary>The 19 canonical joints in wire order (parents before children).</summary>
    public enum Joint
    {
        PELVIS, SPINE, CHEST, NECK, HEAD,
        LEFT_UPPER_ARM, LEFT_FOREARM, LEFT_HAND,
        RIGHT_UPPER_ARM, RIGHT_FOREARM, RIGHT_HAND,
        LEFT_THIGH, LEFT_SHIN, LEFT_FOOT, LEFT_TOE,
        RIGHT_THIGH, RIGHT_SHIN, RIGHT_FOOT, RIGHT_TOE,
    }

    /// <summary>The four tracked points of a frame, in wire order.</summary>
    public enum TrackerSlot { HEAD, LEFT_HAND, RIGHT_HAND, WAIST }

    public static class Protocol
    {
        public const int V1 = 1;
        public const int V2 = 2;
        public const string SubprotocolV1 = "posecast.v1";
        public const string SubprotocolV2 = "posecast.v2";

        public const int NumJoints = 19;
        public const int NumTrackers = 4;
        public const int AllTrackersValid = 0xF;
        public const long UInt32Max = 4294967295L;
        public const double MaxCoordM = 1000.0;
        public const double QuatTolerance = 1e-3;
        public const double MaxTimeS = 1e12;
        public const double MinHeightM = 0.9, MaxHeightM = 2.5;
        public const int MaxIdBytes = 64;
        public const int MaxLookaheadFrames = 255;

        // Structural bounds (v1); v2 lets a server message and its bins reach 16384 bytes.
        public const int MaxDepth = 8;
        public const int MaxArrayLen = 64;
        public const int MaxMapLen = 32;
        public const int MaxStrBytes = 4096;
        public const int MaxBinBytes = 256;
        public const int MaxServerMessageBytesV2 = 16384;
        public const int MaxBinBytesV2 = 16384;

        public static readonly double[] PoseRatesHz = { 60.0, 30.0, 20.0, 15.0 };
        /// <summary>v2: the furthest ahead a client may ask its poses to be forecast, ms.</summary>
        public const double MaxForecastMs = 100.0;
        public static readonly string[] Roles = { "player", "spectator", "backend" };
        public static readonly string[] PresenceEvents = { "join", "leave", "stale", "active" };
        public static readonly string[] SelectorKinds = { "anomaly", "target", "obstacle" };
        public static readonly string[] Layouts = { "hmd3+waist", "hmd3" };

        /// <summary>Joint names as the wire spells them, in joint order.</summary>
        public static readonly string[] JointNames = Enum.GetNames(typeof(Joint));

        /// <summary>Parent of each joint, -1 for the root.</summary>
        public static readonly int[] Parents = { -1, 0, 1, 2, 3, 2, 5, 6, 2, 8, 9, 0, 11, 12, 13, 0, 15, 16, 17 };

        /// <summary>The message types of each version (v2 drops pose for poses).</summary>
        public static readonly HashSet<string> TypesV1 = new HashSet<string>
        { "hello", "welcome", "calibrate", "frame", "pose", "presence", "selector", "kick", "ping", "pong", "error", "bye" };
        public static readonly HashSet<string> TypesV2 = new HashSet<string>
        { "hello", "welcome", "calibrate", "frame", "presence", "selector", "kick", "ping", "pong", "error", "bye",
          "poses", "skeleton", "pose_rate", "resync", "forecast" };
        /// <summary>What clients send in v2 (held to max_message_bytes even on a v2 connection).</summary>
        public static readonly HashSet<string> ClientTypesV2 = new HashSet<string>
        { "hello", "calibrate", "frame", "ping", "bye", "selector", "kick", "pose_rate", "resync", "forecast" };

        public static string Subprotocol(int version) { return version >= V2 ? SubprotocolV2 : SubprotocolV1; }

        /// <summary>The seq after seq (uint32, wraps from 2^32 - 1 to 0).</summary>
        public static uint SeqNext(uint seq) { return unchecked(seq + 1); }

        /// <summary>new - old in serial-number arithmetic (RFC 1982), in [-2^31, 2^31).</summary>
        public static long SeqDelta(long newer, long older)
        {
            long d = (newer - older) & UInt32Max;
            return d >= 2147483648L ? d - 4294967296L : d;
        }
    }

    /// <summary>
    /// Protocol limits. The defaults are the v1 maxima; server config may lower them and
    /// the welcome announces the ones in force.
    /// </summary>
    public sealed class Limits
    {
        public static readonly string[] Names =
        { "max_message_bytes", "max_rate_hz", "max_players", "max_name_bytes", "max_room_bytes",
          "max_token_bytes", "max_text_bytes", "max_watch_rooms" };
        // (floor, v1 maximum) per limit, in Names order.
        public static readonly long[] Floor = { 1024, 1, 1, 1, 1, 0, 64, 0 };
        public static readonly long[] Max = { 8192, 120, 32, 64, 64, 4096, 512, 16 };

        public readonly long[] Values;

        public Limits() { Values = (long[])Max.Clone(); }
        public Limits(long[] values) { Values = values; }

        public static readonly Limits Default = new Limits();

        public int MaxMessageBytes { get { return (int)Values[0]; } }
        public int MaxRateHz { get { return (int)Values[1]; } }
        public int MaxPlayers { get { return (int)Values[2]; } }
        public int MaxNameBytes { get { return (int)Values[3]; } }
        public int MaxRoomBytes { get { return (int)Values[4]; } }
        public int MaxTokenBytes { get { return (int)Values[5]; } }
        public int MaxTextBytes { get { return (int)Values[6]; } }
        public int MaxWatchRooms { get { return (int)Values[7]; } }
    }
}
