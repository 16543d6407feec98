// Unity-only: drives a Humanoid Animator's bones from one remote player's pose,
// sampled from the streamer's jitter buffer at the server's time. The pose's world
// rotation of joint j is the turn from posecast's T-pose rest, so each bone takes
// root * ToUnity(q_j) * rest_j and the hips root.TransformPoint(ToUnity(p_pelvis)), its
// height times the avatar's hips height over the player's rest pelvis height
// (FitToAvatar), with root the Animator's transform and rest_j the bone's rotation relative to it in
// a T-pose facing its root's +Z (docs/game-engines.md): the pose plays in the avatar root's
// frame, wherever the avatar is placed. The T-pose is the one the avatar's Humanoid
// definition holds (Avatar.humanDescription.skeleton, which Unity's avatar setup puts
// in a T-pose), taken at Awake and put back, so a rig that stands in an A-pose or
// any other pose skins correctly; without a definition, the pose it stands in at
// Awake. A PosecastAvatarManager adds one to each avatar it spawns and drives it
// (Apply); placed by hand, it reads its Streamer's jitter buffer for Player. make
// cs-test compiles and tests it against a stand-in UnityEngine (Tests~/UnityStub), not
// in Unity.

using System.Collections.Generic;
using UnityEngine;

namespace Posecast.Client.Unity
{
    public sealed class PosecastAvatarDriver : MonoBehaviour
    {
        [Tooltip("Where the poses come from; unset on avatars a PosecastAvatarManager spawned (it drives them)")]
        public PosecastXRStreamer Streamer;
        public string Player;                 // the remote player's id
        [Tooltip("A Humanoid rig facing its root's +Z; unset: the Animator on this GameObject or below it")]
        public Animator Avatar;
        [Tooltip("Rest from the avatar's Humanoid T-pose; off: from the pose it stands in at Awake (then a T-pose)")]
        public bool RestFromDefinition = true;
        [Tooltip("Scale the hips' height by the avatar's leg length over the player's, so the feet stay on the floor")]
        public bool FitToAvatar = true;

        private Transform[] _bones;
        private Quaternion[] _rest;
        private float _hipsHeight; // the hips above the root in the rest pose, the root's units

        private void Awake()
        {
            if (Avatar == null) Avatar = GetComponentInChildren<Animator>();
            if (Avatar != null) CaptureRest();
        }

        // Each bone's rest rotation in the root's frame (see the file's head), once.
        private void CaptureRest()
        {
            var humans = UnityFrames.HumanBones();
            var toRoot = Quaternion.Inverse(Avatar.transform.rotation);
            _bones = new Transform[humans.Length];
            _rest = new Quaternion[humans.Length];
            var held = RestFromDefinition ? HoldDefinedTPose(Avatar) : null;
            try
            {
                for (int j = 0; j < humans.Length; j++)
                {
                    _bones[j] = Avatar.GetBoneTransform(humans[j]);
                    if (_bones[j] != null) _rest[j] = toRoot * _bones[j].rotation;
                }
                if (_bones[0] != null) _hipsHeight = Avatar.transform.InverseTransformPoint(_bones[0].position).y;
            }
            finally
            {
                if (held != null) for (int i = held.Count - 1; i >= 0; i--) held[i].Key.localRotation = held[i].Value;
            }
        }

        // The avatar's hips height over the player's (the player's rest pelvis height from
        // the pose's own bone lengths): the hips' height is scaled by it, so a shorter or
        // taller avatar stands on the floor; its place across the floor stays the
        // player's (others in the room see it where the player is). 1 when off, or when
        // the avatar's hips stand at its root (no height to fit).
        internal double Fit(Vec3[] positions)
        {
            if (!FitToAvatar || !(_hipsHeight > 0.1f)) return 1.0;
            return _hipsHeight / (Skeleton.RestPelvisHeightM * Skeleton.BodyScale(positions));
        }

        // Puts every transform the avatar's Humanoid definition names (below the Animator's
        // own, which stays where the scene placed it) in its defined T-pose rotation;
        // returns their rotations before, to put back. Null when the avatar has no such
        // definition (no Avatar, not human, no skeleton).
        internal static List<KeyValuePair<Transform, Quaternion>> HoldDefinedTPose(Animator animator)
        {
            var avatar = animator.avatar;
            if (avatar == null || !avatar.isHuman) return null;
            var skeleton = avatar.humanDescription.skeleton;
            if (skeleton == null || skeleton.Length == 0) return null;
            var byName = new Dictionary<string, Transform>();
            foreach (var t in animator.transform.GetComponentsInChildren<Transform>(true))
                if (t != animator.transform && !byName.ContainsKey(t.name)) byName[t.name] = t;
            var held = new List<KeyValuePair<Transform, Quaternion>>();
            foreach (var bone in skeleton)
            {
                Transform t;
                if (bone.name == null || !byName.TryGetValue(bone.name, out t)) continue;
                held.Add(new KeyValuePair<Transform, Quaternion>(t, t.localRotation));
                t.localRotation = bone.rotation;
            }
            return held;
        }

        private void LateUpdate()
        {
            if (Streamer == null || Streamer.Client == null) return;
            Apply(Streamer.Poses.PoseAt(Player, Streamer.Client.ServerNow));
        }

        /// <summary>Pose the avatar's bones as `shown` (a pose without rotations is skipped).</summary>
        public void Apply(InterpolatedPose shown)
        {
            if (shown != null) Apply(shown.Positions, shown.Rotations);
        }

        /// <summary>
        /// Pose the avatar's bones from 19 world positions and rotations (posecast's frame,
        /// joint order; null rotations: skipped). Allocates nothing: call it every frame.
        /// </summary>
        public void Apply(Vec3[] positions, Quat[] rotations)
        {
            if (positions == null || rotations == null) return;
            if (_bones == null)
            {
                if (Avatar == null) return;
                CaptureRest();
            }
            var root = Avatar.transform;
            if (_bones[0] != null)
            {
                var p = positions[0];
                _bones[0].position = root.TransformPoint(UnityFrames.ToUnity(new Vec3(p.X, p.Y * Fit(positions), p.Z)));
            }
            var rootRotation = root.rotation;
            for (int j = 0; j < _bones.Length; j++)
                if (_bones[j] != null) _bones[j].rotation = rootRotation * UnityFrames.ToUnity(rotations[j]) * _rest[j];
        }
    }
}
