// The XR avatars sample: add this component to an empty GameObject in a new scene and
// press Play. It builds the scene at run time (a camera, a light, a floor, a stand-in
// Humanoid when AvatarPrefab is unset) and a PosecastAvatarManager that shows everyone
// in the room:
//
//   XR mode (a headset is connected): a PosecastXRStreamer streams the headset and
//     both controllers through the manager; the camera follows the headset.
//   Desktop mode (no headset, or Mode = Desktop): this player's frames replay the
//     recording Resources/posecast-walk.csv, and its own avatar is shown.
//
// In both a bot (a second connection) replays the recording 1.5 m to the side, so two
// avatars are on screen with one editor. Tokens are minted from the development
// server's secret (posecast serve --dev prints it); a game mints them on its backend
// (PosecastAvatarManager.TokenProvider or a PosecastTokenProvider asset).

using System;
using Posecast.Client;
using Posecast.Client.Unity;
using UnityEngine;
using UnityEngine.XR;

namespace Posecast.Samples
{
    public enum SampleMode { Auto, Desktop, XR }

    public sealed class PosecastSampleBootstrap : MonoBehaviour
    {
        public string Url = "ws://127.0.0.1:8765/";
        [Tooltip("The token secret posecast serve --dev prints (development only)")]
        public string DevSecret = "";
        public string Room = "lobby";
        [Tooltip("Any Humanoid; unset: a stand-in built of capsules")]
        public GameObject AvatarPrefab;
        public SampleMode Mode = SampleMode.Auto;
        [Tooltip("Also start a second player replaying the recording beside you")]
        public bool Bot = true;

        public PosecastAvatarManager Manager { get; private set; }
        public bool Desktop { get; private set; }

        private Transform _camera;

        private void Start()
        {
            Desktop = Mode == SampleMode.Desktop || (Mode == SampleMode.Auto && !InputDevices.GetDeviceAtXRNode(XRNode.Head).isValid);
            BuildScene();
            var recording = TrackerRecording.Parse(Resources.Load<TextAsset>("posecast-walk").text);
            string me = "unity-" + Guid.NewGuid().ToString("N").Substring(0, 6);

            var template = AvatarPrefab;
            if (template == null)
            {
                template = SampleHumanoid.Build("Stand-in Humanoid");
                template.SetActive(false); // a template: the manager shows copies
                template.transform.SetParent(transform, false);
            }
            var room = new GameObject("posecast room");
            Manager = room.AddComponent<PosecastAvatarManager>();
            Manager.ConnectOnStart = false;
            Manager.Url = Url;
            Manager.Room = Room;
            Manager.DisplayName = Desktop ? "Unity (desktop)" : "Unity (XR)";
            Manager.AvatarPrefab = template;
            Manager.ShowLocalAvatar = Desktop;
            string secret = DevSecret, roomName = Room;
            Manager.TokenProvider = () => DevTokens.Mint(secret, roomName, me);
            Manager.PlayerJoined.AddListener(p => Debug.Log("posecast: " + p + " joined"));
            Manager.PlayerLeft.AddListener(p => Debug.Log("posecast: " + p + " left"));
            Manager.Error.AddListener((code, text) => Debug.LogWarning("posecast: " + code + ": " + text));

            if (Desktop)
            {
                var replay = room.AddComponent<SampleReplay>();
                replay.Manager = Manager;
                replay.Recording = recording;
            }
            else
            {
                var rig = new GameObject("XR rig").AddComponent<PosecastXRStreamer>();
                rig.Manager = Manager;
            }
            Connect(recording, me);
        }

        private async void Connect(TrackerRecording recording, string me)
        {
            if (!await Manager.Connect()) return;
            if (!Bot) return;
            var bot = new GameObject("posecast bot").AddComponent<SampleReplay>();
            bot.Recording = recording;
            bot.OffsetM = new Vector3(1.5f, 0f, 0f);
            bot.StartAtS = 2f;
            try { await bot.Connect(Url, DevTokens.Mint(DevSecret, Room, me + "-bot"), Room, "Bot"); }
            catch (Exception e) { Debug.LogWarning("posecast: the bot did not join: " + e.Message); }
        }

        private void BuildScene()
        {
            var camera = Camera.main;
            if (camera == null)
            {
                var go = new GameObject("Main Camera");
                go.tag = "MainCamera";
                camera = go.AddComponent<Camera>();
            }
            _camera = camera.transform;
            // Desktop: behind and above the start, looking along the recording's walk (posecast
            // +Z is Unity +Z; posecast +X, where the walk bends and the bot stands, is Unity -X).
            _camera.position = new Vector3(1.2f, 2.4f, -3.2f);
            _camera.LookAt(new Vector3(-1.2f, 0.9f, 3f));
            if (FindObjectOfType<Light>() == null)
            {
                var light = new GameObject("Sun").AddComponent<Light>();
                light.type = LightType.Directional;
                light.transform.rotation = Quaternion.LookRotation(new Vector3(0.3f, -1f, 0.4f));
            }
            var floor = GameObject.CreatePrimitive(PrimitiveType.Plane);
            floor.name = "Floor";
            floor.transform.localScale = new Vector3(2f, 1f, 2f);
            floor.transform.position = new Vector3(0f, 0f, 3f);
        }

        private void LateUpdate()
        {
            if (Desktop || _camera == null) return;
            var head = InputDevices.GetDeviceAtXRNode(XRNode.Head);
            Vector3 p; Quaternion q;
            if (head.TryGetFeatureValue(CommonUsages.devicePosition, out p) && head.TryGetFeatureValue(CommonUsages.deviceRotation, out q))
            {
                _camera.localPosition = p;
                _camera.localRotation = q;
            }
        }
    }
}
