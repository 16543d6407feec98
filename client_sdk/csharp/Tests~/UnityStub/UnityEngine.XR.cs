// The stand-in's UnityEngine.XR (see API.md): XR input devices a test sets up (FakeDevice),
// the tracking origin of an XR input subsystem.

using System;
using System.Collections.Generic;
using System.Linq;


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
