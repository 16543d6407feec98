// Engine conventions: a posecast pose in Unity's, Unreal's and three.js's frames, and
// posecast's 19 joints by their Unity (HumanBodyBones), VRM and Unreal bone names
// (docs/game-engines.md; checked on proto/vectors/sdk/conventions.json).
//
// posecast's world is right-handed, +Y up, metres; a character faces +Z, its left is
// +X. Each engine's frame is a change of basis p_engine = scale * BASIS p_posecast:
//
//   engine   handedness    up, forward   position          quaternion xyzw
//   unity    left          +Y, +Z        (-x, y, z)        (x, -y, -z, w)
//   unreal   left          +Z, +X        100 (z, -x, y)    (-z, x, -y, w)
//   three    right (same)  +Y, +Z        unchanged         unchanged
//
// A mirror basis (determinant -1: Unity, Unreal) turns a rotation's axis into
// -BASIS axis and keeps its angle's cosine. A pose's rotation of joint j is the turn
// from the T-pose rest (facing +Z) to now, in the world; an engine bone with its own
// rest rotation rest_j (world, avatar in a T-pose facing the engine's forward) takes
// QuatToEngine(q_j) * rest_j.

using System;
using System.Collections.Generic;

namespace Posecast.Client
{
    public enum Engine { Unity, Unreal, Three }

    public static class Conventions
    {
        private sealed class Frame
        {
            public double[] Basis; // 3x3 rows: engine axes in posecast coordinates
            public double Scale;
            public bool RightHanded;
        }

        private static Frame FrameOf(Engine e)
        {
            switch (e)
            {
                case Engine.Unity: return new Frame { Basis = new double[] { -1, 0, 0, 0, 1, 0, 0, 0, 1 }, Scale = 1.0, RightHanded = false };
                case Engine.Unreal: return new Frame { Basis = new double[] { 0, 0, 1, -1, 0, 0, 0, 1, 0 }, Scale = 100.0, RightHanded = false };
                default: return new Frame { Basis = new double[] { 1, 0, 0, 0, 1, 0, 0, 0, 1 }, Scale = 1.0, RightHanded = true };
            }
        }

        private static readonly Frame[] Frames = { FrameOf(Engine.Unity), FrameOf(Engine.Unreal), FrameOf(Engine.Three) };

        public static Engine Parse(string name)
        {
            switch (name)
            {
                case "unity": return Engine.Unity;
                case "unreal": return Engine.Unreal;
                case "three": return Engine.Three;
                default: throw new ArgumentException("no engine " + name);
            }
        }

        private static Vec3 Mul(double[] m, Vec3 v)
        {
            return new Vec3(m[0] * v.X + m[1] * v.Y + m[2] * v.Z, m[3] * v.X + m[4] * v.Y + m[5] * v.Z, m[6] * v.X + m[7] * v.Y + m[8] * v.Z);
        }

        private static Vec3 MulT(double[] m, Vec3 v)
        {
            return new Vec3(m[0] * v.X + m[3] * v.Y + m[6] * v.Z, m[1] * v.X + m[4] * v.Y + m[7] * v.Z, m[2] * v.X + m[5] * v.Y + m[8] * v.Z);
        }

        /// <summary>A posecast position (metres) in the engine's frame and units.</summary>
        public static Vec3 PosToEngine(Vec3 p, Engine e)
        {
            var f = Frames[(int)e];
            return Mul(f.Basis, p) * f.Scale;
        }

        /// <summary>An engine position back to posecast metres.</summary>
        public static Vec3 EngineToPos(Vec3 p, Engine e)
        {
            var f = Frames[(int)e];
            var v = MulT(f.Basis, p);
            return new Vec3(v.X / f.Scale, v.Y / f.Scale, v.Z / f.Scale);
        }

        /// <summary>A posecast rotation xyzw as the engine's xyzw (Quaternion, FQuat, THREE.Quaternion).</summary>
        public static Quat QuatToEngine(Quat q, Engine e)
        {
            var f = Frames[(int)e];
            double det = f.RightHanded ? 1.0 : -1.0;
            var v = Mul(f.Basis, new Vec3(q.X, q.Y, q.Z));
            return new Quat(det * v.X, det * v.Y, det * v.Z, q.W);
        }

        /// <summary>An engine rotation back to posecast (tracker orientations read from an XR API).</summary>
        public static Quat EngineToQuat(Quat q, Engine e)
        {
            var f = Frames[(int)e];
            double det = f.RightHanded ? 1.0 : -1.0;
            var v = MulT(f.Basis, new Vec3(q.X, q.Y, q.Z));
            return new Quat(det * v.X, det * v.Y, det * v.Z, q.W);
        }

        /// <summary>
        /// A posecast head rotation to the orientation of a WebXR viewer or three.js camera at
        /// it (turned 180 degrees about its own Y: q * (0, 1, 0, 0)); its own inverse up to sign.
        /// </summary>
        public static Quat HeadToXrView(Quat q) { return new Quat(-q.Z, q.W, q.X, -q.Y); }

        /// <summary>Positions and rotations of a whole pose in an engine's frame (rotations may be null).</summary>
        public static void PoseToEngine(Vec3[] positions, Quat[] rotations, Engine e, out Vec3[] enginePositions, out Quat[] engineRotations)
        {
            enginePositions = new Vec3[positions.Length];
            for (int j = 0; j < positions.Length; j++) enginePositions[j] = PosToEngine(positions[j], e);
            engineRotations = null;
            if (rotations == null) return;
            engineRotations = new Quat[rotations.Length];
            for (int j = 0; j < rotations.Length; j++) engineRotations[j] = QuatToEngine(rotations[j], e);
        }

        /// <summary>The rigs of the bone table, in its column order.</summary>
        public static readonly string[] BoneRigs = { "unity", "vrm", "unreal", "unreal_ue4" };

        // joint: (Unity HumanBodyBones, VRM humanoid, UE5 Manny, UE4 Mannequin). The rigs'
        // extra bones (shoulders, upper chest, UE5's spine_02/04, neck_02) have no posecast
        // joint: leave them at their rest pose.
        private static readonly string[,] BoneTable =
        {
            { "Hips", "hips", "pelvis", "pelvis" },
            { "Spine", "spine", "spine_01", "spine_01" },
            { "Chest", "chest", "spine_05", "spine_03" },
            { "Neck", "neck", "neck_01", "neck_01" },
            { "Head", "head", "head", "head" },
            { "LeftUpperArm", "leftUpperArm", "upperarm_l", "upperarm_l" },
            { "LeftLowerArm", "leftLowerArm", "lowerarm_l", "lowerarm_l" },
            { "LeftHand", "leftHand", "hand_l", "hand_l" },
            { "RightUpperArm", "rightUpperArm", "upperarm_r", "upperarm_r" },
            { "RightLowerArm", "rightLowerArm", "lowerarm_r", "lowerarm_r" },
            { "RightHand", "rightHand", "hand_r", "hand_r" },
            { "LeftUpperLeg", "leftUpperLeg", "thigh_l", "thigh_l" },
            { "LeftLowerLeg", "leftLowerLeg", "calf_l", "calf_l" },
            { "LeftFoot", "leftFoot", "foot_l", "foot_l" },
            { "LeftToes", "leftToes", "ball_l", "ball_l" },
            { "RightUpperLeg", "rightUpperLeg", "thigh_r", "thigh_r" },
            { "RightLowerLeg", "rightLowerLeg", "calf_r", "calf_r" },
            { "RightFoot", "rightFoot", "foot_r", "foot_r" },
            { "RightToes", "rightToes", "ball_r", "ball_r" },
        };

        /// <summary>The bone of a rig ("unity": a HumanBodyBones name, "vrm", "unreal", "unreal_ue4").</summary>
        public static string BoneName(Joint j, string rig)
        {
            int k = Array.IndexOf(BoneRigs, rig);
            if (k < 0) throw new ArgumentException("no bone rig " + rig);
            return BoneTable[(int)j, k];
        }

        /// <summary>The Unity HumanBodyBones name of each joint, in joint order.</summary>
        public static string[] UnityHumanBones()
        {
            var o = new string[Protocol.NumJoints];
            for (int j = 0; j < o.Length; j++) o[j] = BoneTable[j, 0];
            return o;
        }
    }
}
