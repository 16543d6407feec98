/**
 * The encoders (pure): a message in, its canonical wire map out (`proto/README.md`,
 * "Canonical encoding"): `type` first and then the fields in spec order, absent
 * optionals left out, every float field as {@link Float64}, everything else in its
 * smallest form. `codec.ts`'s `encode` packs the map. They write whatever fields a
 * message has, so they serve both protocol versions.
 */

import { LIMIT_RANGES, type Limits, type Message, type Tracker } from "./messages.js";
import { Float64, type Wire, type WireMap } from "./msgpack.js";
import { pos2mm, quat2snorm } from "./quantize.js";

const f = (v: number): Float64 => new Float64(v);

/** Build a map in the given (canonical) order, leaving out undefined values. */
function wireMap(entries: readonly (readonly [string, Wire | undefined])[]): Map<string, Wire> {
  const out = new Map<string, Wire>();
  for (const [k, v] of entries) if (v !== undefined) out.set(k, v);
  return out;
}

function trackersWire(trackers: readonly Tracker[]): Wire[] {
  return trackers.map((row) => row.map(f));
}

/** The canonical wire map of `msg` (keys in canonical order, floats as {@link Float64}). */
export function toWire(msg: Message): WireMap {
  switch (msg.type) {
    case "hello":
      return wireMap([
        ["type", "hello"],
        ["version", msg.version],
        ["token", msg.token],
        ["room", msg.room],
        ["name", msg.name],
        ["layout", msg.layout],
        ["rate_hz", msg.rate_hz === undefined ? undefined : f(msg.rate_hz)],
        ["watch", msg.watch !== undefined && msg.watch.length > 0 ? [...msg.watch] : undefined],
        ["pose_rate_hz", msg.pose_rate_hz === undefined ? undefined : f(msg.pose_rate_hz)],
        ["forecast_ms", msg.forecast_ms === undefined ? undefined : f(msg.forecast_ms)],
      ]);
    case "welcome":
      return wireMap([
        ["type", "welcome"],
        ["version", msg.version],
        ["player", msg.player],
        ["session", msg.session],
        ["role", msg.role],
        ["room", msg.room],
        ["t", f(msg.t)],
        ["rate_hz", f(msg.rate_hz)],
        ["lookahead_frames", msg.lookahead_frames],
        [
          "members",
          msg.members.map((p) =>
            wireMap([
              ["player", p.player],
              ["name", p.name],
              ["handle", p.avatarId], // the avatar id's wire key
              ["skeleton", p.skeleton],
            ]),
          ),
        ],
        ["limits", wireMap(Object.keys(LIMIT_RANGES).map((k) => [k, msg.limits[k as keyof Limits]]))],
        ["pose_rate_hz", msg.pose_rate_hz === undefined ? undefined : f(msg.pose_rate_hz)],
        ["forecast_ms", msg.forecast_ms === undefined ? undefined : f(msg.forecast_ms)],
      ]);
    case "calibrate":
      return "height_m" in msg
        ? wireMap([
            ["type", "calibrate"],
            ["height_m", f(msg.height_m)],
          ])
        : wireMap([
            ["type", "calibrate"],
            ["tpose", true],
            "sites" in msg ? ["sites", trackersWire(msg.sites)] : ["trackers", trackersWire(msg.trackers)],
          ]);
    case "frame": {
      const rows = "sites" in msg ? msg.sites : msg.trackers;
      const full = 2 ** rows.length - 1;
      return wireMap([
        ["type", "frame"],
        ["seq", msg.seq],
        ["t", f(msg.t)],
        "sites" in msg ? ["sites", trackersWire(msg.sites)] : ["trackers", trackersWire(msg.trackers)],
        ["valid", msg.valid === undefined || msg.valid === full ? undefined : msg.valid],
      ]);
    }
    case "pose": {
      const [root, posMm] = pos2mm(msg.positions);
      return wireMap([
        ["type", "pose"],
        ["player", msg.player],
        ["seq", msg.seq],
        ["t", f(msg.t)],
        ["root", root.map(f)],
        ["pos_mm", posMm],
        ["rot", msg.rotations === undefined ? undefined : quat2snorm(msg.rotations)],
      ]);
    }
    case "presence":
      return wireMap([
        ["type", "presence"],
        ["event", msg.event],
        ["room", msg.room],
        ["player", msg.player],
        ["name", msg.name],
        ["handle", msg.avatarId], // the avatar id's wire key
        ["skeleton", msg.skeleton],
      ]);
    case "selector":
      return wireMap([
        ["type", "selector"],
        ["player", msg.player],
        ["kind", msg.kind],
        ["joint", msg.joint],
        ["point", msg.point?.map(f)],
        ["radius_m", msg.radius_m === undefined ? undefined : f(msg.radius_m)],
        ["margin_m", msg.margin_m === undefined ? undefined : f(msg.margin_m)],
        ["factor", msg.factor === undefined ? undefined : f(msg.factor)],
      ]);
    case "kick":
      return wireMap([
        ["type", "kick"],
        ["player", msg.player],
        ["reason", msg.reason],
      ]);
    case "ping":
      return wireMap([
        ["type", "ping"],
        ["t0", f(msg.t0)],
      ]);
    case "pong":
      return wireMap([
        ["type", "pong"],
        ["t0", f(msg.t0)],
        ["t1", f(msg.t1)],
        ["t2", f(msg.t2)],
      ]);
    case "error":
      return wireMap([
        ["type", "error"],
        ["code", msg.code],
        ["message", msg.message],
        ["fatal", msg.fatal],
        ["field", msg.field],
        ["ref_seq", msg.ref_seq],
      ]);
    case "bye":
      return wireMap([
        ["type", "bye"],
        ["reason", msg.reason],
      ]);
    case "poses":
      return wireMap([
        ["type", "poses"],
        ["t", f(msg.t)],
        ["data", msg.data],
      ]);
    case "skeleton":
      return wireMap([
        ["type", "skeleton"],
        ["player", msg.player],
        ["handle", msg.avatarId], // the avatar id's wire key
        ["skeleton", msg.skeleton],
      ]);
    case "pose_rate":
      return wireMap([
        ["type", "pose_rate"],
        ["rate_hz", f(msg.rate_hz)],
      ]);
    case "resync":
      return wireMap([["type", "resync"]]);
    case "forecast":
      return wireMap([
        ["type", "forecast"],
        ["ms", f(msg.ms)],
      ]);
  }
}
