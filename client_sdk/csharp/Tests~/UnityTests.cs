// Runtime/Unity on the stand-in UnityEngine (Tests~/UnityStub): the avatar driver's
// bone mapping (rest rotations from the avatar's Humanoid T-pose or its Awake pose, the
// avatar's own root), and what the XR streamer
// reads from Unity's XR input (lost tracking, the tracking origin).

using System;
using System.Reflection;
using Posecast.Client.Unity;
using UnityEngine;
using UnityEngine.XR;

namespace Posecast.Client.Tests
{
    public static class UnityTests
    {
        private static void Near(Vector3 want, Vector3 got, double tol, string what)
        {
            T.Near(new Vec3(want.x, want.y, want.z), new Vec3(got.x, got.y, got.z), tol, what);
        }

        private static Quaternion Yaw(float deg) { return Quaternion.AngleAxis(deg, new Vector3(0, 1, 0)); }

        /// <summary>A Humanoid avatar whose root is at `rootPos`, turned by `rootRot`, standing in a
        /// T-pose facing its root's +Z; every bone's local +Y runs along the bone (a common rig).</summary>
        private static Animator Avatar(Vector3 rootPos, Quaternion rootRot)
        {
            var a = new Animator();
            a.transform = new Transform { position = rootPos, rotation = rootRot };
            var names = Conventions.UnityHumanBones();
            for (int j = 0; j < names.Length; j++)
            {
                var bone = (HumanBodyBones)Enum.Parse(typeof(HumanBodyBones), names[j]);
                // In the root's frame: left arm bones point +Y at root -X (the avatar's left, Unity),
                // right arm bones at +X; the rest keep the root's axes.
                Quaternion local = Quaternion.identity;
                if (names[j].StartsWith("LeftUpperArm") || names[j].StartsWith("LeftLowerArm") || names[j] == "LeftHand")
                    local = Quaternion.AngleAxis(90, new Vector3(0, 0, 1));   // +Y -> -X
                if (names[j].StartsWith("RightUpperArm") || names[j].StartsWith("RightLowerArm") || names[j] == "RightHand")
                    local = Quaternion.AngleAxis(-90, new Vector3(0, 0, 1));  // +Y -> +X
                a.Bones[bone] = new Transform { position = rootPos, rotation = rootRot * local };
            }
            return a;
        }

        private static PosecastAvatarDriver Driver(Animator avatar)
        {
            var d = new PosecastAvatarDriver { Avatar = avatar };
            typeof(PosecastAvatarDriver).GetMethod("Awake", BindingFlags.Instance | BindingFlags.NonPublic).Invoke(d, null);
            return d;
        }

        /// <summary>The reference T-pose with some joints turned (posecast world, xyzw).</summary>
        private static InterpolatedPose Pose(Vec3 pelvis, params object[] turns)
        {
            var pos = new Vec3[Protocol.NumJoints];
            var rot = new Quat[Protocol.NumJoints];
            for (int j = 0; j < rot.Length; j++) { pos[j] = pelvis; rot[j] = Quat.Identity; }
            for (int i = 0; i < turns.Length; i += 2) rot[(int)(Joint)turns[i]] = (Quat)turns[i + 1];
            return new InterpolatedPose { Player = "p", Positions = pos, Rotations = rot };
        }

        private static Quat AxisAngle(double x, double y, double z, double deg)
        {
            double h = deg * Math.PI / 360.0;
            return new Quat(x * Math.Sin(h), y * Math.Sin(h), z * Math.Sin(h), Math.Cos(h));
        }

        private static readonly Vector3 Up = new Vector3(0, 1, 0), Fwd = new Vector3(0, 0, 1);

        public static void Register()
        {
            T.Run("unity driver: the T-pose is the rest pose, and an arm lowered in posecast hangs down in Unity", () =>
            {
                var avatar = Avatar(Vector3.zero, Quaternion.identity);
                var d = Driver(avatar);
                d.Apply(Pose(new Vec3(0, 0.98, 0)));
                Near(new Vector3(0, 0.98f, 0), avatar.GetBoneTransform(HumanBodyBones.Hips).position, 1e-6, "hips");
                Near(new Vector3(-1, 0, 0), avatar.GetBoneTransform(HumanBodyBones.LeftUpperArm).rotation * Up, 1e-6, "left arm at rest");
                // posecast: the left arm (+X) turned down about the forward axis: -90 degrees about +Z.
                d.Apply(Pose(new Vec3(0, 0.98, 0), Joint.LEFT_UPPER_ARM, AxisAngle(0, 0, 1, -90)));
                Near(new Vector3(0, -1, 0), avatar.GetBoneTransform(HumanBodyBones.LeftUpperArm).rotation * Up, 1e-6, "left arm down");
            });

            T.Run("unity driver: an avatar placed and turned in the scene moves in its own root's frame", () =>
            {
                var root = Yaw(90); // the avatar faces Unity +X
                var avatar = Avatar(new Vector3(2, 0, 3), root);
                var d = Driver(avatar);
                // A nod: the head turned 30 degrees about posecast +X (its left), looking down.
                d.Apply(Pose(new Vec3(0.5, 0.98, 0), Joint.HEAD, AxisAngle(1, 0, 0, 30)));
                var hips = avatar.GetBoneTransform(HumanBodyBones.Hips);
                // posecast (0.5, 0.98, 0) is Unity (-0.5, 0.98, 0) in the root's frame: root * that + (2, 0, 3).
                Near(new Vector3(2, 0.98f, 3.5f), hips.position, 1e-6, "hips in the root's frame");
                Near(new Vector3(1, 0, 0), hips.rotation * Fwd, 1e-6, "hips face the root's forward");
                var face = avatar.GetBoneTransform(HumanBodyBones.Head).rotation * Fwd;
                Near(new Vector3((float)Math.Cos(Math.PI / 6), -0.5f, 0), face, 1e-6, "the head nods along the root's forward");
            });

            // float32 rotations composed through a hierarchy: 1e-5.
            T.Run("unity driver: an avatar standing in an A-pose takes its rest from its Humanoid T-pose, and is put back", () =>
            {
                // root -> Hips -> LeftUpperArm -> LeftLowerArm; each bone's local +Y along it.
                // At Awake the arm hangs 45 degrees down from the T-pose; the definition holds the T-pose.
                var tposeArm = Quaternion.AngleAxis(90, new Vector3(0, 0, 1));   // +Y -> -X (the avatar's left)
                var aposeArm = Quaternion.AngleAxis(135, new Vector3(0, 0, 1));  // 45 degrees below it
                Func<bool, Animator> build = (defined) =>
                {
                    var a = new Animator();
                    a.transform = new Transform { name = "Ada", position = new Vector3(1, 0, 0), rotation = Yaw(90) };
                    var hips = new Transform { name = "Hips" }; hips.parent = a.transform; hips.localRotation = Quaternion.identity;
                    var upper = new Transform { name = "LeftUpperArm" }; upper.parent = hips; upper.localRotation = aposeArm;
                    var lower = new Transform { name = "LeftLowerArm" }; lower.parent = upper; lower.localRotation = Quaternion.identity;
                    a.Bones[HumanBodyBones.Hips] = hips;
                    a.Bones[HumanBodyBones.LeftUpperArm] = upper;
                    a.Bones[HumanBodyBones.LeftLowerArm] = lower;
                    if (defined)
                        a.avatar = new UnityEngine.Avatar
                        {
                            isHuman = true,
                            humanDescription = new HumanDescription
                            {
                                skeleton = new[]
                                {
                                    new SkeletonBone { name = "Ada", rotation = Yaw(-30) },  // the root's own: not touched
                                    new SkeletonBone { name = "Hips", rotation = Quaternion.identity },
                                    new SkeletonBone { name = "LeftUpperArm", rotation = tposeArm },
                                    new SkeletonBone { name = "LeftLowerArm", rotation = Quaternion.identity },
                                },
                            },
                        };
                    return a;
                };
                var avatar = build(true);
                var root = avatar.transform;
                var d = Driver(avatar);
                var arm = avatar.GetBoneTransform(HumanBodyBones.LeftUpperArm);
                Near(new Vector3(0, 0, 0), new Vector3(arm.localRotation.x - aposeArm.x, arm.localRotation.y - aposeArm.y, arm.localRotation.z - aposeArm.z), 1e-5, "the A-pose put back after Awake");
                T.NearRot(new Quat(Yaw(90).x, Yaw(90).y, Yaw(90).z, Yaw(90).w), new Quat(root.rotation.x, root.rotation.y, root.rotation.z, root.rotation.w), 1e-5, "the root left where the scene placed it");
                d.Apply(Pose(new Vec3(0, 0.98, 0)));
                Near(root.rotation * new Vector3(-1, 0, 0), arm.rotation * Up, 1e-5, "posecast's rest pose: the arm straight out to the avatar's left");
                Near(root.rotation * new Vector3(-1, 0, 0), avatar.GetBoneTransform(HumanBodyBones.LeftLowerArm).rotation * Up, 1e-5, "the forearm too");
                d.Apply(Pose(new Vec3(0, 0.98, 0), Joint.LEFT_UPPER_ARM, AxisAngle(0, 0, 1, -90)));
                Near(new Vector3(0, -1, 0), arm.rotation * Up, 1e-5, "an arm lowered in posecast hangs down");
                // Without the definition the pose at Awake is taken for the T-pose: the arm stays 45 degrees low.
                var bare = build(false);
                Driver(bare).Apply(Pose(new Vec3(0, 0.98, 0)));
                var low = bare.GetBoneTransform(HumanBodyBones.LeftUpperArm).rotation * Up;
                Near(bare.transform.rotation * (aposeArm * Up), low, 1e-5, "no definition: the Awake pose is the rest");
            });

            T.Run("unity driver: the hips' place is fitted to the avatar's legs, so its feet stay on the floor", () =>
            {
                // An avatar whose hips stand 0.8 m above its root (shorter legs than the reference body's 0.98 m).
                var avatar = Avatar(new Vector3(2, 0, 3), Yaw(90));
                avatar.GetBoneTransform(HumanBodyBones.Hips).position = avatar.transform.TransformPoint(new Vector3(0, 0.8f, 0));
                var d = Driver(avatar);
                var hips = avatar.GetBoneTransform(HumanBodyBones.Hips);
                var world = new Quat[19];
                for (int j = 0; j < 19; j++) world[j] = Quat.Identity;
                Func<double, Vec3, InterpolatedPose> player = (size, pelvis) =>
                {
                    var offsets = Skeleton.ReferenceOffsets();
                    for (int j = 0; j < offsets.Length; j++) offsets[j] = offsets[j] * size;
                    return new InterpolatedPose { Player = "p", Positions = Skeleton.ForwardKinematics(pelvis, world, offsets), Rotations = world };
                };
                // A reference-sized player standing 0.5 m to its left and 1 m forward: the hips at
                // 0.8 m, across the floor where the player is (others see the avatar there).
                d.Apply(player(1.0, new Vec3(0.5, 0.98, 1.0)));
                Near(avatar.transform.TransformPoint(new Vector3(-0.5f, 0.8f, 1.0f)), hips.position, 1e-5, "fitted");
                d.Apply(player(1.0, new Vec3(0, 0.49, 0))); // crouching: half the height, fitted alike
                Near(avatar.transform.TransformPoint(new Vector3(0, 0.4f, 0)), hips.position, 1e-5, "crouching");
                d.Apply(player(1.1, new Vec3(0, 0.98 * 1.1, 0))); // a taller player standing: the same avatar height
                Near(avatar.transform.TransformPoint(new Vector3(0, 0.8f, 0)), hips.position, 1e-5, "a taller player");
                d.FitToAvatar = false;
                d.Apply(player(1.0, new Vec3(0, 0.98, 0)));
                Near(avatar.transform.TransformPoint(new Vector3(0, 0.98f, 0)), hips.position, 1e-5, "off: posecast's metres");
            });

            T.Run("unity streamer: a controller that lost tracking is not read as tracked", () =>
            {
                var read = typeof(PosecastXRStreamer).GetMethod("Read", BindingFlags.Static | BindingFlags.NonPublic);
                var dev = new FakeDevice();
                dev.Features["DevicePosition"] = new Vector3(0.3f, 1.1f, 0.2f);
                dev.Features["DeviceRotation"] = Quaternion.identity;
                dev.Features["IsTracked"] = true;
                InputDevices.Fakes[XRNode.LeftHand] = dev;
                try
                {
                    var args = new object[] { XRNode.LeftHand, null, null };
                    T.True((bool)read.Invoke(null, args), "tracked: read");
                    Near(new Vector3(0.3f, 1.1f, 0.2f), (Vector3)args[1], 1e-6, "position");
                    dev.Features["IsTracked"] = false; // out of the cameras' view: Unity keeps the last pose
                    args = new object[] { XRNode.LeftHand, null, null };
                    T.True(!(bool)read.Invoke(null, args), "lost tracking: not read (sent untracked, not frozen)");
                    InputDevices.Fakes[XRNode.Head] = dev; // the head keeps its held position, as in fromXRFrame
                    args = new object[] { XRNode.Head, null, null };
                    T.True((bool)read.Invoke(null, args), "a head that lost positional tracking is still read");
                }
                finally { InputDevices.Fakes.Remove(XRNode.LeftHand); InputDevices.Fakes.Remove(XRNode.Head); }
            });

            T.Run("unity streamer: reads the headset and controllers in posecast's frame for frames and the T-pose", () =>
            {
                var read = typeof(PosecastXRStreamer).GetMethod("ReadTrackers", BindingFlags.Static | BindingFlags.NonPublic);
                var head = new FakeDevice();
                head.Features["DevicePosition"] = new Vector3(0.1f, 1.6f, 0.2f);
                head.Features["DeviceRotation"] = Quaternion.identity;
                var right = new FakeDevice();
                right.Features["DevicePosition"] = new Vector3(0.7f, 1.4f, 0.2f);
                right.Features["DeviceRotation"] = Quaternion.identity;
                right.Features["IsTracked"] = true;
                InputDevices.Fakes[XRNode.Head] = head;
                InputDevices.Fakes[XRNode.RightHand] = right;
                try
                {
                    var pos = new Vec3[4]; var rot = new Quat[4];
                    pos[3] = new Vec3(9, 9, 9);
                    T.Equal(0b101, (int)read.Invoke(null, new object[] { pos, rot }), "head and right hand; the left controller is absent");
                    T.Near(UnityFrames.FromUnity(new Vector3(0.7f, 1.4f, 0.2f)), pos[2], 0, "right hand in posecast's frame");
                    T.Near(Vec3.Zero, pos[1], 0, "an absent controller goes as the origin");
                    T.Near(Vec3.Zero, pos[3], 0, "the waist slot (hmd3 ignores it) goes as the origin");
                    var streamer = new PosecastXRStreamer();
                    T.True(!streamer.CalibrateTPoseAsync().Result, "not joined: no T-pose sent");
                }
                finally { InputDevices.Fakes.Remove(XRNode.Head); InputDevices.Fakes.Remove(XRNode.RightHand); }
            });

            T.Run("unity streamer: asks for a floor-level tracking origin (y = height above the floor)", () =>
            {
                var ask = typeof(PosecastXRStreamer).GetMethod("RequestFloor", BindingFlags.Static | BindingFlags.NonPublic);
                T.True(ask != null, "PosecastXRStreamer.RequestFloor");
                T.True(!(bool)ask.Invoke(null, new object[] { null }), "no subsystem yet: ask again later");
                var sub = new XRInputSubsystem { Mode = TrackingOriginModeFlags.Device };
                T.True((bool)ask.Invoke(null, new object[] { sub }), "settled");
                T.Equal(TrackingOriginModeFlags.Floor, sub.Mode, "origin");
                var eyeOnly = new XRInputSubsystem { Mode = TrackingOriginModeFlags.Device, Supported = TrackingOriginModeFlags.Device };
                int warned = UnityEngine.Debug.Warnings.Count;
                T.True((bool)ask.Invoke(null, new object[] { eyeOnly }), "settled (cannot)");
                T.Equal(warned + 1, UnityEngine.Debug.Warnings.Count, "warned once");
            });
        }
    }
}
