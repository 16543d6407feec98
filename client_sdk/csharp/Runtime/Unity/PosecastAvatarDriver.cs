// Unity-only: drives a Humanoid Animator's bones from one remote player's pose,
// sampled from the streamer's jitter buffer at the server's time. The pose's world
// rotation of joint j is the turn from posecast's T-pose rest, so each bone takes
// root * ToUnity(q_j) * rest_j and the hips root.TransformPoint(ToUnity(p_pelvis)),
// with root the Animator's transform and rest_j the bone's rotation relative to it,
// captured while the avatar stands in a T-pose facing its root's +Z (docs/engines.md):
// the pose plays in the avatar root's frame, wherever the avatar is placed. make cs-test
// compiles and tests it against a stand-in UnityEngine (Tests~/UnityStub), not in Unity.

using UnityEngine;

namespace Posecast.Client.Unity
{
    public sealed class PosecastAvatarDriver : MonoBehaviour
    {
        public PosecastXRStreamer Streamer;
        public string Player;                 // the remote player's id
        public Animator Avatar;               // a Humanoid rig, in a T-pose facing its root's +Z at Awake

        private Transform[] _bones;
        private Quaternion[] _rest;

        private void Awake()
        {
            var humans = UnityFrames.HumanBones();
            var toRoot = Quaternion.Inverse(Avatar.transform.rotation);
            _bones = new Transform[humans.Length];
            _rest = new Quaternion[humans.Length];
            for (int j = 0; j < humans.Length; j++)
            {
                _bones[j] = Avatar.GetBoneTransform(humans[j]);
                if (_bones[j] != null) _rest[j] = toRoot * _bones[j].rotation;
            }
        }

        private void LateUpdate()
        {
            if (Streamer == null || Streamer.Client == null) return;
            Apply(Streamer.Poses.PoseAt(Player, Streamer.Client.ServerNow));
        }

        /// <summary>Pose the avatar's bones as `shown` (a pose without rotations is skipped).</summary>
        public void Apply(InterpolatedPose shown)
        {
            if (shown == null || shown.Rotations == null) return;
            var root = Avatar.transform;
            if (_bones[0] != null) _bones[0].position = root.TransformPoint(UnityFrames.ToUnity(shown.Positions[0]));
            for (int j = 0; j < _bones.Length; j++)
                if (_bones[j] != null) _bones[j].rotation = root.rotation * UnityFrames.ToUnity(shown.Rotations[j]) * _rest[j];
        }
    }
}
