// Unity-only: drives a Humanoid Animator's bones from one remote player's pose,
// sampled from the streamer's jitter buffer at the server's time. The pose's world
// rotation of joint j is the turn from posecast's T-pose rest, so each bone takes
// ToUnity(q_j) * rest_j, with rest_j the bone's world rotation captured while the
// avatar stands in a T-pose facing +Z (docs/engines.md). NOT compiled or run by
// make cs-test (it needs UnityEngine).

using UnityEngine;

namespace Posecast.Client.Unity
{
    public sealed class PosecastAvatarDriver : MonoBehaviour
    {
        public PosecastXRStreamer Streamer;
        public string Player;                 // the remote player's id
        public Animator Avatar;               // a Humanoid rig, in a T-pose facing +Z at Awake

        private Transform[] _bones;
        private Quaternion[] _rest;

        private void Awake()
        {
            var humans = UnityFrames.HumanBones();
            _bones = new Transform[humans.Length];
            _rest = new Quaternion[humans.Length];
            for (int j = 0; j < humans.Length; j++)
            {
                _bones[j] = Avatar.GetBoneTransform(humans[j]);
                if (_bones[j] != null) _rest[j] = _bones[j].rotation;
            }
        }

        private void LateUpdate()
        {
            if (Streamer == null || Streamer.Client == null) return;
            var shown = Streamer.Poses.PoseAt(Player, Streamer.Client.ServerNow);
            if (shown == null || shown.Rotations == null) return;
            if (_bones[0] != null) _bones[0].position = UnityFrames.ToUnity(shown.Positions[0]);
            for (int j = 0; j < _bones.Length; j++)
                if (_bones[j] != null) _bones[j].rotation = UnityFrames.ToUnity(shown.Rotations[j]) * _rest[j];
        }
    }
}
