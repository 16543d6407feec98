#!/usr/bin/env bash
# make cs-test: build the C# SDK and its test runner with Mono's mcs, then run them.
#
# Installs Debian's mono-devel where it can (root with apt-get); where it cannot, it
# prints one SKIPPED line and exits 0. Outputs go to build/csharp/.
set -euo pipefail
cd "$(dirname "$0")/../../.."
OUT=build/csharp
SDK=client_sdk/csharp

have_mono() { command -v mcs >/dev/null 2>&1 && command -v mono >/dev/null 2>&1; }
if ! have_mono && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
  echo "cs-test: installing mono-devel with apt-get"
  export DEBIAN_FRONTEND=noninteractive
  apt-get install -y -qq mono-devel >/dev/null 2>&1 \
    || { apt-get update -qq >/dev/null 2>&1 && apt-get install -y -qq mono-devel >/dev/null 2>&1; } || true
fi
if ! have_mono; then
  echo "cs-test: SKIPPED: no Mono here (mcs, mono) and it cannot be installed (needs root and apt-get)"
  exit 0
fi

mkdir -p "$OUT"
# C# 7.3 where the compiler knows it; Mono 6.8's mcs stops at 7.2, which is a subset.
echo 'class Probe {}' > "$OUT/probe.cs"
LANGV=7.3
mcs -langversion:7.3 -target:library -nologo -out:"$OUT/probe.dll" "$OUT/probe.cs" >/dev/null 2>&1 || LANGV=7.2
MCS=(mcs -langversion:$LANGV -nologo -warnaserror+ -debug-)

"${MCS[@]}" -target:library -out:"$OUT/Posecast.Client.dll" "$SDK"/Runtime/Core/*.cs
# Runtime/Unity against a stand-in UnityEngine (Tests~/UnityStub): compiled and its
# logic tested here; it still needs a real Unity and a headset to be tried for real.
"${MCS[@]}" -target:library -out:"$OUT/UnityEngine.dll" "$SDK"/Tests~/UnityStub/*.cs
"${MCS[@]}" -target:library -r:"$OUT/Posecast.Client.dll" -r:"$OUT/UnityEngine.dll" \
  -out:"$OUT/Posecast.Client.Unity.dll" "$SDK"/Runtime/Unity/*.cs
# The XR avatars sample, against the same stand-in (its desktop mode runs in SampleTests).
"${MCS[@]}" -target:library -r:"$OUT/Posecast.Client.dll" -r:"$OUT/UnityEngine.dll" -r:"$OUT/Posecast.Client.Unity.dll" \
  -out:"$OUT/Posecast.Samples.XRAvatars.dll" "$SDK"/Samples~/XRAvatars/*.cs
# ApiTests reads the Unity assemblies' references to UnityEngine with Mono.Cecil (mono-devel's).
CECIL=()
for dll in /usr/lib/mono/gac/Mono.Cecil/0.11*/Mono.Cecil.dll; do [ -f "$dll" ] && CECIL=(-define:CECIL -r:"$dll"); done
"${MCS[@]}" -r:"$OUT/Posecast.Client.dll" -r:"$OUT/UnityEngine.dll" -r:"$OUT/Posecast.Client.Unity.dll" \
  -r:"$OUT/Posecast.Samples.XRAvatars.dll" "${CECIL[@]}" -r:System.Core.dll -out:"$OUT/PosecastTests.exe" "$SDK"/Tests~/*.cs
echo "cs-test: built with mcs -langversion:$LANGV ($(mcs --version))"
exec mono "$OUT/PosecastTests.exe" --repo "$PWD" "$@"
