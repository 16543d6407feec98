// The wire messages (v1 and v2) as typed values. One class per message type; its
// fields, in declaration order, are the wire fields in canonical key order
// (proto/README.md; Codec turns these into bytes and back). A null field is absent.
//
// Arrays: tracker positions and orientations have 4 entries in TrackerSlot order;
// pose positions and rotations 19 in Joint order.

namespace Posecast.Client
{
    /// <summary>Base of every wire message; Type is the wire "type".</summary>
    public abstract class Message
    {
        public abstract string Type { get; }
    }

    /// <summary>Client to server, first message, every role. Watch: backends only.</summary>
    public sealed class Hello : Message
    {
        public override string Type { get { return "hello"; } }
        public long Version = Protocol.V1;
        public string Token = "";
        public string Room = "";
        public string Name = "";
        public string Layout;          // null: the server takes "hmd3+waist"
        public double? RateHz;         // frames per second the client will send; null: 60
        public string[] Watch = new string[0];
        public double? PoseRateHz;     // v2: poses per second to receive; null: 60
        public double? ForecastMs;     // v2: poses forecast this many ms ahead, 0-100; null: none
    }

    /// <summary>A player in a room. v2 adds its avatar id and skeleton (108 bytes).</summary>
    public sealed class Member
    {
        public string Player;
        public string Name;
        public long? AvatarId;         // v2: how pose records name this player ("handle" on the wire)
        public byte[] Skeleton;
    }

    /// <summary>Server to client, the answer to a good hello.</summary>
    public sealed class Welcome : Message
    {
        public override string Type { get { return "welcome"; } }
        public long Version;
        public string Player;          // this connection's id
        public string Session;
        public string Role;
        public string Room;
        public double T;               // server time, seconds
        public double RateHz;          // the room's pose rate (the engine tick)
        public long LookaheadFrames;   // poses lag their source frames by this many frames
        public Member[] Members = new Member[0];
        public Limits Limits = Limits.Default;
        public double? PoseRateHz;     // v2: the poses per second this client gets
        public double? ForecastMs;     // v2: when asked: how far ahead its poses are (whole ticks)
    }

    /// <summary>Player to server: by standing height, or by a T-pose frame.</summary>
    public sealed class Calibrate : Message
    {
        public override string Type { get { return "calibrate"; } }
        public double? HeightM;
        public Vec3[] Positions;       // the T-pose frame (4 slots, or a set's sites), when by T-pose
        public Quat[] Orientations;
        public bool Sites;             // the T-pose is a tracker set's (`sites` on the wire)
        public bool TPose { get { return Positions != null; } }
    }

    /// <summary>Player to server: one tracker frame. Untracked slots read as origin + identity.</summary>
    public sealed class Frame : Message
    {
        public override string Type { get { return "frame"; } }
        public long Seq;
        public double T;               // client time, seconds
        public Vec3[] Positions = new Vec3[Protocol.NumTrackers];  // a set's: one per site (m, or m/s^2 for an IMU)
        public Quat[] Orientations = new Quat[Protocol.NumTrackers];
        public int Valid = Protocol.AllTrackersValid;
        public bool Sites;             // a tracker set's frame (`sites` on the wire, not `trackers`)
    }

    /// <summary>v1 server to client: one reconstructed avatar (quantised on the wire).</summary>
    public sealed class Pose : Message
    {
        public override string Type { get { return "pose"; } }
        public string Player;
        public long Seq;               // seq of the source frame
        public double T;               // server time, seconds
        public Vec3[] Positions;       // 19 world positions
        public Quat[] Rotations;       // 19 world rotations, or null
    }

    public sealed class Presence : Message
    {
        public override string Type { get { return "presence"; } }
        public string Event;           // join | leave | stale | active
        public string Room;
        public string Player;
        public string Name;
        public long? AvatarId;         // v2 join ("handle" on the wire)
        public byte[] Skeleton;        // v2 join
    }

    /// <summary>v2 server to client: every pose of one tick for this client, as records.</summary>
    public sealed class Poses : Message
    {
        public override string Type { get { return "poses"; } }
        public double T;
        public byte[] Data;
    }

    /// <summary>v2 server to client: a player's calibration changed; FK with this from now on.</summary>
    public sealed class SkeletonMessage : Message
    {
        public override string Type { get { return "skeleton"; } }
        public string Player;
        public long AvatarId;           // "handle" on the wire
        public byte[] Skeleton;
    }

    /// <summary>v2 client to server: receive RateHz poses per second (60, 30, 20 or 15).</summary>
    public sealed class PoseRate : Message
    {
        public override string Type { get { return "pose_rate"; } }
        public double RateHz;
    }

    /// <summary>v2 client to server: receive poses forecast Ms (0-100) milliseconds ahead, 0 for
    /// none; the server rounds it to whole ticks and stamps each poses.t that far past its tick.</summary>
    public sealed class Forecast : Message
    {
        public override string Type { get { return "forecast"; } }
        public double Ms;
    }

    /// <summary>v2 client to server: send a keyframe of every avatar with the next poses.</summary>
    public sealed class Resync : Message
    {
        public override string Type { get { return "resync"; } }
    }

    /// <summary>Backend to server: choose how a player's samples are selected.</summary>
    public sealed class Selector : Message
    {
        public override string Type { get { return "selector"; } }
        public string Player;
        public string Kind;
        public string Joint;
        public Vec3? Point;
        public double? RadiusM;
        public double? MarginM;
        public double? Factor;
    }

    public sealed class Kick : Message
    {
        public override string Type { get { return "kick"; } }
        public string Player;
        public string Reason;
    }

    public sealed class Ping : Message
    {
        public override string Type { get { return "ping"; } }
        public double T0;              // client time at send
    }

    /// <summary>offset = ((t1 - t0) + (t2 - t3)) / 2, rtt = (t3 - t0) - (t2 - t1).</summary>
    public sealed class Pong : Message
    {
        public override string Type { get { return "pong"; } }
        public double T0, T1, T2;
    }

    /// <summary>Server to client: a refused message, or the end of the connection (Fatal).</summary>
    public sealed class ErrorMessage : Message
    {
        public override string Type { get { return "error"; } }
        public string Code;
        public string Text = "";       // the wire's "message"
        public bool Fatal;
        public string Field;
        public long? RefSeq;

        /// <summary>The matching typed exception.</summary>
        public ProtocolException ToException()
        {
            return ProtocolException.FromWire(Code, Text, Fatal, Field, RefSeq);
        }
    }

    public sealed class Bye : Message
    {
        public override string Type { get { return "bye"; } }
        public string Reason;
    }
}
