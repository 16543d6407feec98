// The stand-in's Humanoid animation types (see API.md): Avatar, HumanDescription and its
// bones, AvatarBuilder, HumanBodyBones and Animator.

using System;
using System.Collections.Generic;
using System.Linq;

namespace UnityEngine
{
    public sealed class Avatar : Object
    {
        // Unity: read-only; the stand-in lets a test set them.
        public bool isHuman { get; set; }
        public bool isValid { get; set; }
        public HumanDescription humanDescription { get; set; }
    }

    public struct HumanDescription
    {
        public HumanBone[] human;
        public SkeletonBone[] skeleton;
        public float upperArmTwist { get; set; }
        public float lowerArmTwist { get; set; }
        public float upperLegTwist { get; set; }
        public float lowerLegTwist { get; set; }
        public float armStretch { get; set; }
        public float legStretch { get; set; }
        public float feetSpacing { get; set; }
        public bool hasTranslationDoF { get; set; }
    }

    /// <summary>A Transform's name and its T-pose in its parent's space (Unity's SkeletonBone).</summary>
    public struct SkeletonBone
    {
        public string name;
        public Vector3 position;
        public Quaternion rotation;
        public Vector3 scale;
    }

    /// <summary>Which Transform (boneName) is which human bone (humanName, HumanTrait.BoneName's spelling).</summary>
    public struct HumanBone
    {
        public string boneName { get; set; }
        public string humanName { get; set; }
        public HumanLimit limit;
    }

    public struct HumanLimit
    {
        public bool useDefaultValues { get; set; }
        public Vector3 min { get; set; }
        public Vector3 max { get; set; }
        public Vector3 center { get; set; }
        public float axisLength { get; set; }
    }

    public static class AvatarBuilder
    {
        private static readonly string[] Required =
        {
            "Hips", "LeftUpperLeg", "RightUpperLeg", "LeftLowerLeg", "RightLowerLeg", "LeftFoot", "RightFoot", "Spine", "Head",
            "LeftUpperArm", "RightUpperArm", "LeftLowerArm", "RightLowerArm", "LeftHand", "RightHand",
        };

        /// <summary>A Humanoid Avatar for the hierarchy under `go`: valid when every required human
        /// bone is mapped to a Transform found by name below it.</summary>
        public static Avatar BuildHumanAvatar(GameObject go, HumanDescription humanDescription)
        {
            var names = new HashSet<string>();
            foreach (var t in go.transform.GetComponentsInChildren<Transform>(true)) names.Add(t.name);
            bool valid = humanDescription.human != null;
            foreach (var r in Required)
                valid &= humanDescription.human != null && humanDescription.human.Any(h => h.humanName == r && names.Contains(h.boneName));
            return new Avatar { isHuman = true, isValid = valid, humanDescription = humanDescription, name = go.name };
        }
    }

    public enum HumanBodyBones
    {
        Hips, LeftUpperLeg, RightUpperLeg, LeftLowerLeg, RightLowerLeg, LeftFoot, RightFoot, Spine, Chest, Neck, Head,
        LeftShoulder, RightShoulder, LeftUpperArm, RightUpperArm, LeftLowerArm, RightLowerArm, LeftHand, RightHand,
        LeftToes, RightToes, LeftEye, RightEye, Jaw, UpperChest = 54, LastBone = 55,
    }

    public class Animator : Behaviour
    {
        public Avatar avatar { get; set; }
        public readonly Dictionary<HumanBodyBones, Transform> Bones = new Dictionary<HumanBodyBones, Transform>();
        /// <summary>The Transform of a human bone: through the Humanoid avatar's mapping (Unity's way),
        /// or the test-only Bones table of rigs built without one.</summary>
        public Transform GetBoneTransform(HumanBodyBones b)
        {
            Transform t;
            if (Bones.TryGetValue(b, out t)) return t;
            if (avatar == null || !avatar.isHuman || avatar.humanDescription.human == null) return null;
            foreach (var h in avatar.humanDescription.human)
                if (h.humanName == b.ToString())
                    foreach (var c in transform.GetComponentsInChildren<Transform>(true))
                        if (c.name == h.boneName) return c;
            return null;
        }

        internal override void CopyTo(GameObject into, Dictionary<Transform, Transform> map)
        {
            var a = into.AddComponent<Animator>();
            a.avatar = avatar;
            foreach (var kv in Bones) a.Bones[kv.Key] = map[kv.Value];
        }
    }
}
