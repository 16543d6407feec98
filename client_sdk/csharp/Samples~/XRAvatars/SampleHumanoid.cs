// The sample's stand-in avatar, built at run time so an empty project has a Humanoid
// to show: posecast's reference skeleton (19 bones, in its T-pose, facing +Z) with a
// capsule along each bone and a sphere for the head, made a Humanoid by
// AvatarBuilder.BuildHumanAvatar. Any rigged Humanoid model does instead (the
// bootstrap's AvatarPrefab).

using Posecast.Client;
using Posecast.Client.Unity;
using UnityEngine;

namespace Posecast.Samples
{
    public static class SampleHumanoid
    {
        /// <summary>A new inactive-looking template: a root with an Animator and a Humanoid Avatar.</summary>
        public static GameObject Build(string name)
        {
            var root = new GameObject(name);
            var humans = UnityFrames.HumanBones();
            var offsets = Skeleton.ReferenceOffsets();
            var bones = new Transform[Protocol.NumJoints];
            var description = new HumanDescription
            {
                human = new HumanBone[Protocol.NumJoints],
                skeleton = new SkeletonBone[Protocol.NumJoints + 1],
                upperArmTwist = 0.5f, lowerArmTwist = 0.5f, upperLegTwist = 0.5f, lowerLegTwist = 0.5f,
                armStretch = 0.05f, legStretch = 0.05f, feetSpacing = 0f, hasTranslationDoF = false,
            };
            description.skeleton[0] = new SkeletonBone { name = name, position = Vector3.zero, rotation = Quaternion.identity, scale = Vector3.one };
            for (int j = 0; j < Protocol.NumJoints; j++)
            {
                var bone = new GameObject(humans[j].ToString()).transform;
                int parent = Protocol.Parents[j];
                bone.SetParent(parent < 0 ? root.transform : bones[parent], false);
                bone.localPosition = parent < 0
                    ? new Vector3(0f, (float)Skeleton.RestPelvisHeightM, 0f)
                    : UnityFrames.ToUnity(offsets[j - 1]);
                bone.localRotation = Quaternion.identity;
                bones[j] = bone;
                description.human[j] = new HumanBone { boneName = bone.name, humanName = humans[j].ToString(), limit = new HumanLimit { useDefaultValues = true } };
                description.skeleton[j + 1] = new SkeletonBone { name = bone.name, position = bone.localPosition, rotation = Quaternion.identity, scale = Vector3.one };
                if (parent >= 0) Limb(bones[parent], bone.localPosition, j == (int)Joint.HEAD ? 0.06f : 0.045f);
            }
            Head(bones[(int)Joint.HEAD]);
            var animator = root.AddComponent<Animator>();
            animator.avatar = AvatarBuilder.BuildHumanAvatar(root, description);
            if (!animator.avatar.isValid) Debug.LogWarning("posecast sample: the built avatar is not a valid Humanoid");
            return root;
        }

        // A capsule from a bone to its child at `toChild` (the child's place in the bone's frame).
        private static void Limb(Transform from, Vector3 toChild, float radius)
        {
            float length = toChild.magnitude;
            if (length < 1e-3f) return;
            var capsule = GameObject.CreatePrimitive(PrimitiveType.Capsule);
            capsule.name = "limb";
            Object.Destroy(capsule.GetComponent<Collider>());
            capsule.transform.SetParent(from, false);
            capsule.transform.localPosition = toChild * 0.5f;
            capsule.transform.localRotation = Quaternion.FromToRotation(Vector3.up, toChild);
            capsule.transform.localScale = new Vector3(2 * radius, length * 0.5f, 2 * radius);
        }

        private static void Head(Transform head)
        {
            var sphere = GameObject.CreatePrimitive(PrimitiveType.Sphere);
            sphere.name = "head";
            Object.Destroy(sphere.GetComponent<Collider>());
            sphere.transform.SetParent(head, false);
            sphere.transform.localPosition = new Vector3(0f, 0.08f, 0f);
            sphere.transform.localScale = new Vector3(0.2f, 0.24f, 0.22f);
        }
    }
}
