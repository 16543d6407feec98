// A stand-in for the few UnityEngine types Runtime/Unity uses, so run.sh can compile
// the Unity layer and test its logic on Mono (UnityTests.cs). Same names and
// signatures as Unity's; the behaviour is the part the tests need (Quaternion's
// Hamilton product, a Transform hierarchy without scale, an Avatar's T-pose skeleton, XR devices the test sets up).
// Not shipped: Unity does not import Tests~.

using System;
using System.Collections.Generic;

namespace UnityEngine
{
    public class Object { }

    public class Component : Object
    {
        private Transform _transform;
        public Transform transform { get { return _transform ?? (_transform = this as Transform ?? new Transform()); } set { _transform = value; } }

        public T[] GetComponentsInChildren<T>(bool includeInactive) where T : Component
        {
            var all = new List<Transform>();
            transform.Walk(all);
            var found = new List<T>();
            foreach (var t in all) if (t is T) found.Add((T)(Component)t);
            return found.ToArray();
        }
    }

    public class Behaviour : Component { }
    public class MonoBehaviour : Behaviour { }

    public sealed class TooltipAttribute : Attribute { public TooltipAttribute(string tooltip) { } }

    public static class Debug
    {
        public static readonly List<string> Warnings = new List<string>();
        public static void LogWarning(object message) { Warnings.Add(message == null ? "" : message.ToString()); }
    }

    public struct Vector3
    {
        public float x, y, z;
        public Vector3(float x, float y, float z) { this.x = x; this.y = y; this.z = z; }
        public static Vector3 zero { get { return new Vector3(0, 0, 0); } }
        public static Vector3 operator +(Vector3 a, Vector3 b) { return new Vector3(a.x + b.x, a.y + b.y, a.z + b.z); }
        public static Vector3 operator -(Vector3 a, Vector3 b) { return new Vector3(a.x - b.x, a.y - b.y, a.z - b.z); }
        public override string ToString() { return "(" + x + ", " + y + ", " + z + ")"; }
    }

    public struct Quaternion
    {
        public float x, y, z, w;
        public Quaternion(float x, float y, float z, float w) { this.x = x; this.y = y; this.z = z; this.w = w; }
        public static Quaternion identity { get { return new Quaternion(0, 0, 0, 1); } }

        public static Quaternion operator *(Quaternion a, Quaternion b)
        {
            return new Quaternion(
                a.w * b.x + a.x * b.w + a.y * b.z - a.z * b.y,
                a.w * b.y + a.y * b.w + a.z * b.x - a.x * b.z,
                a.w * b.z + a.z * b.w + a.x * b.y - a.y * b.x,
                a.w * b.w - a.x * b.x - a.y * b.y - a.z * b.z);
        }

        public static Vector3 operator *(Quaternion q, Vector3 v)
        {
            var r = q * new Quaternion(v.x, v.y, v.z, 0) * Inverse(q);
            return new Vector3(r.x, r.y, r.z);
        }

        public static Quaternion Inverse(Quaternion q) { return new Quaternion(-q.x, -q.y, -q.z, q.w); }

        public static Quaternion AngleAxis(float angle, Vector3 axis)
        {
            double h = angle * Math.PI / 360.0, n = Math.Sqrt(axis.x * axis.x + axis.y * axis.y + axis.z * axis.z);
            double s = Math.Sin(h) / n;
            return new Quaternion((float)(axis.x * s), (float)(axis.y * s), (float)(axis.z * s), (float)Math.Cos(h));
        }

        public override string ToString() { return "(" + x + ", " + y + ", " + z + ", " + w + ")"; }
    }

    /// <summary>Position and rotation, local to an optional parent (no scale). Setting
    /// `parent` keeps the world pose, as Unity's does.</summary>
    public class Transform : Component
    {
        public string name = "";
        public Vector3 localPosition;
        public Quaternion localRotation = Quaternion.identity;
        private Transform _parent;
        private readonly List<Transform> _children = new List<Transform>();

        public Transform parent
        {
            get { return _parent; }
            set
            {
                Vector3 p = position; Quaternion q = rotation;
                if (_parent != null) _parent._children.Remove(this);
                _parent = value;
                if (value != null) value._children.Add(this);
                position = p; rotation = q;
            }
        }

        public Vector3 position
        {
            get { return _parent == null ? localPosition : _parent.TransformPoint(localPosition); }
            set { localPosition = _parent == null ? value : Quaternion.Inverse(_parent.rotation) * (value - _parent.position); }
        }

        public Quaternion rotation
        {
            get { return _parent == null ? localRotation : _parent.rotation * localRotation; }
            set { localRotation = _parent == null ? value : Quaternion.Inverse(_parent.rotation) * value; }
        }

        public Vector3 TransformPoint(Vector3 p) { return position + rotation * p; }
        public Vector3 InverseTransformPoint(Vector3 p) { return Quaternion.Inverse(rotation) * (p - position); }

        internal void Walk(List<Transform> into)
        {
            into.Add(this);
            foreach (var c in _children) c.Walk(into);
        }
    }

    public sealed class Avatar : Object
    {
        public bool isHuman;
        public HumanDescription humanDescription;  // Unity: a read-only property
    }

    public struct HumanDescription
    {
        public SkeletonBone[] skeleton;
    }

    /// <summary>A Transform's name and its T-pose in its parent's space (Unity's SkeletonBone).</summary>
    public struct SkeletonBone
    {
        public string name;
        public Vector3 position;
        public Quaternion rotation;
        public Vector3 scale;
    }

    public enum HumanBodyBones
    {
        Hips, LeftUpperLeg, RightUpperLeg, LeftLowerLeg, RightLowerLeg, LeftFoot, RightFoot, Spine, Chest, Neck, Head,
        LeftShoulder, RightShoulder, LeftUpperArm, RightUpperArm, LeftLowerArm, RightLowerArm, LeftHand, RightHand,
        LeftToes, RightToes, LeftEye, RightEye, Jaw, UpperChest = 54, LastBone = 55,
    }

    public class Animator : Behaviour
    {
        public Avatar avatar;
        public readonly Dictionary<HumanBodyBones, Transform> Bones = new Dictionary<HumanBodyBones, Transform>();
        public Transform GetBoneTransform(HumanBodyBones b) { Transform t; return Bones.TryGetValue(b, out t) ? t : null; }
    }
}

namespace UnityEngine.XR
{
    public enum XRNode { LeftEye, RightEye, CenterEye, Head, LeftHand, RightHand, GameController, TrackingReference, HardwareTracker }

    [Flags]
    public enum TrackingOriginModeFlags { Unknown = 0, Device = 1, Floor = 2, TrackingReference = 4, Unbounded = 8 }

    public class XRInputSubsystem
    {
        public TrackingOriginModeFlags Mode = TrackingOriginModeFlags.Device;
        public TrackingOriginModeFlags Supported = TrackingOriginModeFlags.Device | TrackingOriginModeFlags.Floor;
        public TrackingOriginModeFlags GetTrackingOriginMode() { return Mode; }
        public TrackingOriginModeFlags GetSupportedTrackingOriginModes() { return Supported; }
        public bool TrySetTrackingOriginMode(TrackingOriginModeFlags origin)
        {
            if ((Supported & origin) == 0) return false;
            Mode = origin;
            return true;
        }
    }

    public struct InputFeatureUsage<T>
    {
        public string name;
        public InputFeatureUsage(string name) { this.name = name; }
    }

    public static class CommonUsages
    {
        public static readonly InputFeatureUsage<bool> isTracked = new InputFeatureUsage<bool>("IsTracked");
        public static readonly InputFeatureUsage<Vector3> devicePosition = new InputFeatureUsage<Vector3>("DevicePosition");
        public static readonly InputFeatureUsage<Quaternion> deviceRotation = new InputFeatureUsage<Quaternion>("DeviceRotation");
    }

    /// <summary>A test device: its features by usage name; absent: TryGetFeatureValue fails.</summary>
    public sealed class FakeDevice
    {
        public XRInputSubsystem Subsystem;
        public readonly Dictionary<string, object> Features = new Dictionary<string, object>();
    }

    public struct InputDevice
    {
        internal FakeDevice Fake;
        public bool isValid { get { return Fake != null; } }
        public XRInputSubsystem subsystem { get { return Fake == null ? null : Fake.Subsystem; } }

        private bool Get<T>(string name, out T value)
        {
            object o;
            if (Fake != null && Fake.Features.TryGetValue(name, out o)) { value = (T)o; return true; }
            value = default(T);
            return false;
        }

        public bool TryGetFeatureValue(InputFeatureUsage<bool> usage, out bool value) { return Get(usage.name, out value); }
        public bool TryGetFeatureValue(InputFeatureUsage<Vector3> usage, out Vector3 value) { return Get(usage.name, out value); }
        public bool TryGetFeatureValue(InputFeatureUsage<Quaternion> usage, out Quaternion value) { return Get(usage.name, out value); }
    }

    public static class InputDevices
    {
        public static readonly Dictionary<XRNode, FakeDevice> Fakes = new Dictionary<XRNode, FakeDevice>();
        public static InputDevice GetDeviceAtXRNode(XRNode node)
        {
            FakeDevice d;
            return new InputDevice { Fake = Fakes.TryGetValue(node, out d) ? d : null };
        }
    }
}
