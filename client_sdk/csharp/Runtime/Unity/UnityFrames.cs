// Unity-only: posecast values <-> Unity's Vector3/Quaternion (left-handed, +Y up,
// metres). Every conversion is Conventions' (tested on proto/vectors/sdk/
// conventions.json); this file only changes the types. make cs-test compiles it against
// a stand-in UnityEngine (Tests~/UnityStub), not in Unity.

using UnityEngine;

namespace Posecast.Client.Unity
{
    public static class UnityFrames
    {
        public static Vector3 ToUnity(Vec3 p)
        {
            var e = Conventions.PosToEngine(p, Engine.Unity);
            return new Vector3((float)e.X, (float)e.Y, (float)e.Z);
        }

        public static Quaternion ToUnity(Quat q)
        {
            var e = Conventions.QuatToEngine(q, Engine.Unity);
            return new Quaternion((float)e.X, (float)e.Y, (float)e.Z, (float)e.W);
        }

        public static Vec3 FromUnity(Vector3 p) { return Conventions.EngineToPos(new Vec3(p.x, p.y, p.z), Engine.Unity); }

        public static Quat FromUnity(Quaternion q) { return Conventions.EngineToQuat(new Quat(q.x, q.y, q.z, q.w), Engine.Unity); }

        /// <summary>The HumanBodyBones of each posecast joint, in joint order.</summary>
        public static HumanBodyBones[] HumanBones()
        {
            var names = Conventions.UnityHumanBones();
            var bones = new HumanBodyBones[names.Length];
            for (int j = 0; j < names.Length; j++) bones[j] = (HumanBodyBones)System.Enum.Parse(typeof(HumanBodyBones), names[j]);
            return bones;
        }
    }
}
