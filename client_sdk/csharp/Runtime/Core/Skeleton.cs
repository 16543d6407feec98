// The canonical 19-joint skeleton and FK from streamed rotations.
//
// World: right-handed, +Y up, metres; a character faces +Z in its rest pose and its
// left is +X. The rest pose (every local rotation identity) is a T-pose. Joint j's
// world position is p[parent] + R_world[parent] offsets[j], with the bone offsets a v2
// server announces per player (welcome, presence join, skeleton) or the reference
// body's. Mirrors server/posecast/skeleton.py and the other SDKs' skeleton modules.

namespace Posecast.Client
{
    public static class Skeleton
    {
        // Rest offsets from the parent of the reference body (about 1.75 m tall), metres,
        // for SPINE .. RIGHT_TOE (PELVIS has none).
        private static readonly double[] ReferenceM =
        {
            0.0, 0.10, 0.0,    0.0, 0.20, 0.0,    0.0, 0.22, 0.0,    0.0, 0.10, 0.0,     // SPINE CHEST NECK HEAD
            0.17, 0.17, 0.0,   0.28, 0.0, 0.0,    0.25, 0.0, 0.0,                        // LEFT arm
            -0.17, 0.17, 0.0,  -0.28, 0.0, 0.0,   -0.25, 0.0, 0.0,                       // RIGHT arm
            0.09, -0.05, 0.0,  0.0, -0.43, 0.0,   0.0, -0.42, 0.0,   0.0, -0.06, 0.13,   // LEFT leg
            -0.09, -0.05, 0.0, 0.0, -0.43, 0.0,   0.0, -0.42, 0.0,   0.0, -0.06, 0.13,   // RIGHT leg
        };

        /// <summary>The reference body's 18 bone offsets (SPINE..RIGHT_TOE), metres, a fresh copy.</summary>
        public static Vec3[] ReferenceOffsets()
        {
            var o = new Vec3[Protocol.NumJoints - 1];
            for (int j = 0; j < o.Length; j++) o[j] = new Vec3(ReferenceM[3 * j], ReferenceM[3 * j + 1], ReferenceM[3 * j + 2]);
            return o;
        }

        /// <summary>The reference body's PELVIS height above the floor in its rest pose, metres.</summary>
        public const double RestPelvisHeightM = 0.98;

        public static int Parent(Joint j) { return Protocol.Parents[(int)j]; }

        /// <summary>
        /// A pose's body size against the reference body: the sum of its 18 bone lengths
        /// over the reference's (a calibration scales every bone alike, so one number
        /// fits the whole body; the TypeScript viewer's poseToBones scale). 1 for a pose
        /// whose joints all coincide.
        /// </summary>
        public static double BodyScale(Vec3[] positions)
        {
            double bones = 0;
            for (int j = 1; j < Protocol.NumJoints; j++) bones += (positions[j] - positions[Protocol.Parents[j]]).Length;
            return bones > 1e-6 ? bones / ReferenceBoneSumM : 1.0;
        }

        private static readonly double ReferenceBoneSumM = BoneSum(ReferenceOffsets());

        private static double BoneSum(Vec3[] offsets)
        {
            double sum = 0;
            foreach (var o in offsets) sum += o.Length;
            return sum;
        }

        /// <summary>Joint positions from the PELVIS position, the 19 world rotations and 18 bone offsets.</summary>
        public static Vec3[] ForwardKinematics(Vec3 root, Quat[] world, Vec3[] offsets)
        {
            return Records.Positions(root, world, offsets);
        }

        /// <summary>World rotations from local ones (PELVIS world first), parents before children.</summary>
        public static Quat[] LocalToWorld(Quat[] local) { return Records.ItemsToWorld(local); }

        /// <summary>Each joint's rotation relative to its parent (PELVIS: its world rotation).</summary>
        public static Quat[] WorldToLocal(Quat[] world) { return Records.WorldToItems(world); }
    }
}
