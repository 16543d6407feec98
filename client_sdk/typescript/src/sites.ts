/**
 * Tracker sets: which body sites a player tracks and what each tracker reports
 * (`proto/README.md`, hello `layout`; the server's `posecast.tracking.sites`).
 *
 * A set is a `hello.layout` listing sites in the order the player's `frame.sites` rows
 * come in, an inertial (IMU) site suffixed `:imu`, e.g.
 * `head,left_hand,right_hand,waist,left_foot:imu,right_foot:imu`. A positional row is
 * `[x, y, z, qx, qy, qz, qw]` with the world position in metres; an inertial row has
 * the world linear acceleration with gravity removed (m/s^2) where the position would
 * be. Head and both hands are required and positional.
 */

import { LAYOUTS, type Tracker } from "./messages.js";
import { checkedRow, type TrackerPose, UNTRACKED } from "./trackers.js";

/** The ten sites, in the model's row order. */
export const SITES = [
  "head",
  "left_hand",
  "right_hand",
  "waist",
  "left_foot",
  "right_foot",
  "left_knee",
  "right_knee",
  "left_elbow",
  "right_elbow",
] as const;
export type Site = (typeof SITES)[number];
export const MAX_SITES = SITES.length;
export const INERTIAL_SUFFIX = ":imu";
/** hello.layout: the longest set's name is 124 bytes. */
export const MAX_LAYOUT_BYTES = 128;

/** The joint each site's tracker sits on (its position; the orientation of that bone). */
export const SITE_JOINTS: Readonly<Record<Site, string>> = {
  head: "HEAD",
  left_hand: "LEFT_HAND",
  right_hand: "RIGHT_HAND",
  waist: "PELVIS",
  left_foot: "LEFT_FOOT", // the ankle; the foot's rotation
  right_foot: "RIGHT_FOOT",
  left_knee: "LEFT_SHIN", // the knee; the shin's rotation (strapped below it)
  right_knee: "RIGHT_SHIN",
  left_elbow: "LEFT_FOREARM", // the elbow; the forearm's rotation
  right_elbow: "RIGHT_FOREARM",
};

const REQUIRED: readonly Site[] = ["head", "left_hand", "right_hand"];

/** A parsed set: its sites in wire order and whether each is inertial. */
export interface TrackerSet {
  readonly name: string;
  readonly sites: readonly Site[];
  readonly inertial: readonly boolean[];
}

/**
 * The set a layout string names. Throws `RangeError` saying why not, with the
 * server's rule: known sites, none twice, a positional head and both hands.
 */
export function parseTrackerSet(text: string): TrackerSet {
  if (typeof text !== "string" || text.length === 0) {
    throw new RangeError("a tracker set is a non-empty string");
  }
  const sites: Site[] = [];
  const inertial: boolean[] = [];
  for (const token of text.split(",")) {
    const imu = token.endsWith(INERTIAL_SUFFIX);
    const name = imu ? token.slice(0, -INERTIAL_SUFFIX.length) : token;
    if (!(SITES as readonly string[]).includes(name)) throw new RangeError(`unknown site '${name}'`);
    if (sites.includes(name as Site)) throw new RangeError(`site '${name}' listed twice`);
    sites.push(name as Site);
    inertial.push(imu);
  }
  for (const site of REQUIRED) {
    const i = sites.indexOf(site);
    if (i < 0 || inertial[i]) {
      throw new RangeError(`a tracker set needs a ${i < 0 ? "" : "positional "}'${site}' tracker`);
    }
  }
  return { name: text, sites, inertial };
}

/** The set a `hello.layout` names, or undefined for a named layout (or none). */
export function trackerSetOf(layout: string | undefined): TrackerSet | undefined {
  if (layout === undefined || (LAYOUTS as readonly string[]).includes(layout)) return undefined;
  return parseTrackerSet(layout);
}

/** An inertial tracker's reading: world acceleration (gravity removed, m/s^2), orientation. */
export interface ImuReading {
  readonly acceleration: readonly [number, number, number];
  readonly orientation: readonly [number, number, number, number];
}

/** camelCase key of each site in {@link SitesInput}. */
export const SITE_KEYS = {
  head: "head",
  left_hand: "leftHand",
  right_hand: "rightHand",
  waist: "waist",
  left_foot: "leftFoot",
  right_foot: "rightFoot",
  left_knee: "leftKnee",
  right_knee: "rightKnee",
  left_elbow: "leftElbow",
  right_elbow: "rightElbow",
} as const satisfies Record<Site, string>;
type SiteKey = (typeof SITE_KEYS)[Site];

/**
 * One frame of a tracker set by site (camelCase, so a {@link FrameInput} from
 * `fromXRFrame` is one too): a positional site's {@link TrackerPose}, an inertial
 * site's {@link ImuReading}. A site that is absent (or null) is sent untracked.
 */
export type SitesInput = { readonly [K in SiteKey]?: TrackerPose | ImuReading | null } & {
  readonly t?: number;
};

const VALUE = { label: "value", unit: "" } as const;

/**
 * `SitesInput` -> the set's wire rows (`frame.sites`) and the `valid` mask, checked as
 * the server checks them (values finite and within +-1000: OutOfRangeError;
 * orientations finite and not zero: NotNormalisedError; then normalised). A
 * positional site must give a `position`, an inertial one an `acceleration`.
 */
export function toSites(set: TrackerSet, input: SitesInput): { sites: Tracker[]; valid: number } {
  let valid = 0;
  const rows = set.sites.map((site, i): Tracker => {
    const reading = input[SITE_KEYS[site]];
    if (!reading) return UNTRACKED;
    const field = `sites[${i}]`;
    const value = set.inertial[i]
      ? "acceleration" in reading
        ? reading.acceleration
        : undefined
      : "position" in reading
        ? reading.position
        : undefined;
    if (value === undefined) {
      const want = set.inertial[i] ? "an acceleration (inertial)" : "a position (positional)";
      throw new RangeError(`${site}: give ${want}`);
    }
    valid |= 1 << i;
    return checkedRow(value, reading.orientation, site, field, VALUE);
  });
  return { sites: rows, valid };
}
