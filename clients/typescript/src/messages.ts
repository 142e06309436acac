/** The stream's messages as sent, before their id: a frame, a clip, an fk. */

import { framesAsSent, targetsAsSent } from "./targets.js";
import type { BoneOutput, Frame, PoseIn, Target } from "./types.js";

export type Envelope = Record<string, unknown>;

/** What one frame message may add to its targets. */
export interface FrameOptions {
  /** This frame's bone output instead of the session's (skeleton chains; docs/websocket.md). */
  bones?: BoneOutput | undefined;
  /** The animated pose this frame starts from, as `setPose` then the frame in one step. */
  pose?: PoseIn | undefined;
}

/** `fk`'s pose: `q` (every DOF), or `joints` (some, by name; the others: the session's
 * current pose), or neither (the current pose); `bones`: the bone data to return
 * (skeleton chains; the server's default: the local rotations; a chain without bones
 * refuses any). */
export interface FkOptions {
  q?: number[] | undefined;
  joints?: Record<string, number> | undefined;
  bones?: BoneOutput | undefined;
}

export function fkMessage(options: FkOptions): Envelope {
  // The three fields by name: an object with more (a session's `pose`) sends no others.
  const message: Envelope = { type: "fk" };
  if (options.q !== undefined) message["q"] = options.q;
  if (options.joints !== undefined) message["joints"] = options.joints;
  if (options.bones !== undefined) message["bones"] = options.bones;
  return message;
}

export function frameMessage(given: Target[], options: FrameOptions): Envelope {
  const message: Envelope = { type: "frame", targets: targetsAsSent(given) };
  if (options.bones !== undefined) message["bones"] = options.bones;
  if (options.pose !== undefined) message["pose"] = options.pose;
  return message;
}

export function clipMessage(frames: Frame[], options: { plan?: boolean | undefined }): Envelope {
  return { type: "clip", frames: framesAsSent(frames), plan: options.plan ?? false };
}
