/**
 * The chains a session or a one-shot solve is built from (schema `SessionCreate.chain`):
 * joints and effectors as JSON, URDF text, an example built into the server, or a
 * skeleton (glTF, BVH) whose bones are the joints. The server validates a chain and names
 * the field at fault.
 */

import type { EffectorMode, Quaternion, Vec3 } from "./types.js";

/** Schema `OriginSpec`. */
export interface OriginSpec {
  translation?: Vec3;
  rotation?: Quaternion;
}

/** Schema `JointSpec`. */
export interface JointSpec {
  name: string;
  parent: string;
  child: string;
  kind: "fixed" | "rotational" | "revolute" | "continuous" | "prismatic";
  origin?: OriginSpec;
  pivot?: Vec3;
  axis?: Vec3;
  axes?: string;
  lower?: number[];
  upper?: number[];
  terminator?: boolean;
}

/** What an effector on a link (`EffectorSpec`) and on a bone (`BoneEffectorSpec`) both set. */
export interface EffectorSettings {
  tip_offset?: Vec3;
  tip_rotation?: Quaternion;
  mode?: EffectorMode;
  aim_axis?: Vec3;
  position_weight?: number;
  rotation_weight?: number;
}

/** Schema `EffectorSpec`. */
export interface EffectorSpec extends EffectorSettings {
  name: string;
  link: string;
}

/** Schema `HierarchyChain`: joints and effectors as JSON. */
export interface HierarchyChain {
  format: "hierarchy";
  joints: JointSpec[];
  effectors: EffectorSpec[];
}

/** Schema `UrdfChain`: URDF text, from `base_link` to each of `tip_links`. */
export interface UrdfChain {
  format: "urdf";
  urdf: string;
  base_link: string;
  tip_links: string[];
  mode?: EffectorMode;
}

/** Schema `ExampleChain`: a chain built into the server. */
export interface ExampleChain {
  format: "example";
  name: "panda_arm" | "humanoid_arm" | "tail" | "two_arm_torso";
}

/** Schema `BoneEffectorSpec`: an effector on a skeleton bone (named after it by default). */
export interface BoneEffectorSpec extends EffectorSettings {
  bone: string;
  name?: string | null;
}

/** Schema `BoneSettingsSpec`: one bone's axes (intrinsic order), limits [rad], terminator. */
export interface BoneSettingsSpec {
  axes?: string | null;
  lower?: number[] | null;
  upper?: number[] | null;
  terminator?: boolean;
}

/** What skeleton chains (glTF, BVH) share (docs/engines.md, Skeleton formats). */
export interface SkeletonSettings {
  effectors: BoneEffectorSpec[];
  moving?: string[] | null;
  bones?: Record<string, BoneSettingsSpec>;
  default_axes?: string;
  free_root?: { lower?: Vec3; upper?: Vec3 } | null;
}

/**
 * Schema `GltfChain`: a glTF skin's joints as bones (`gltf`: the .gltf JSON, or `glb_base64`);
 * `unit_m`: metres per file unit (1, as glTF says; 0.01 for a centimetre export without a scale node).
 */
export interface GltfChain extends SkeletonSettings {
  format: "gltf";
  gltf?: Record<string, unknown> | null;
  glb_base64?: string | null;
  skin?: number | string | null;
  unit_m?: number;
}

/** Schema `BvhChain`: a BVH file's joints as bones; `unit_m`: metres per file unit. */
export interface BvhChain extends SkeletonSettings {
  format: "bvh";
  bvh: string;
  unit_m?: number;
}

export type Chain = HierarchyChain | UrdfChain | ExampleChain | GltfChain | BvhChain;
